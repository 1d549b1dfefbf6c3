"""Team MCL cost per env step against a bare numpy gather, and PPO throughput with MCL.

``bench_mcl_team()`` returns, measured in one run with the process CPU clock
(``time.process_time``, so time spent descheduled on a shared machine does not
count). Every env step is timed on three identical copies of the env (same seed,
same actions) stepped one after the other, and the fastest copy counts, as the
fastest of the repeated gathers does: on a shared machine another process
contending for the core slows one copy's step, rarely all three (the
``*_all_copies`` figures average every copy instead):

* ``hallway_step_ms``: one ``symmetric_hallway`` env step as shipped (8 sonar
  robots, up to 2000 particles each, 16 beams, detections on; random actions,
  after a warm-up that builds the tables and lets KLD-sampling settle);
* ``hallway_gather_us``: ``numpy.take`` of robots x particles x beams
  (8 x 2000 x 16 = 256,000) float64 values at random indices of a
  2**16-entry table (512 KiB, held in cache: the strict floor), the fastest
  of three gathers after every step, and ``hallway_ratio``, the step over the
  gather; ``hallway_gather_8mib_us`` and ``hallway_ratio_8mib`` are the same
  with a 2**20-entry table (8 MiB, the size class of a map's lookup table);
  with ``without_copies=True`` (``--without-copies``) also ``hallway_step_ms_no_copies``
  and ``hallway_ratio_no_copies``: the same env without its kept symmetric copies
  (``extras["mcl_symmetry_check"] = False``), stepped in alternating blocks with it;
  with ``calibrated_copies=True`` (``--calibrated-copies``) also
  ``hallway_step_ms_calibrated`` and ``hallway_ratio_calibrated``: the same env with
  the kept copies sharing the weight (``extras["mcl_calibrated_copies"] = True``),
  stepped in alternating blocks with it;
* ``outdoor_mcl_extra_us_per_robot``: in ``outdoor_terrain`` with 4 robots,
  1000 particles and 30 laser beams, the CPU time per robot and step that
  ``estimator="mcl"`` adds over ``estimator="ekf"`` (fixed particle count; the two
  are stepped in alternating blocks of five steps, twice the hallway's step count
  each, so both see the same machine load), and ``outdoor_ratio``, that over a
  30,000-value gather of the same kind;
* with ``training=True``, ``ppo_hallway_agent_steps_per_s``: PPO agent steps
  per wall-clock second on ``symmetric_hallway`` with 4 robots and 1000
  particles (``scripts/bench/training.py``'s settings otherwise);
* with ``memory=True``, ``tables_mb_*``: the lookup tables each shipped
  scenario builds (:func:`table_memory_mb`), and ``table_err_*``: the range
  tables' error against exact ray casts (:func:`table_accuracy`).

Run ``python scripts/bench/mcl_team.py --help`` for the options.
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

import coop_loc_env
from coop_loc_env.cli import ScriptParser, run_script

__all__ = ["bench_mcl_team", "table_accuracy", "table_memory_mb", "timed_steps"]

TABLE_ENTRIES = 2**20
SMALL_TABLE_ENTRIES = 2**16  # 512 KiB: stays in cache, the strictest floor


def _gather_arrays(rng: np.random.Generator, gather_n: int, tables: tuple[int, ...]) -> list:
    """A random table of each size in ``tables`` and ``gather_n`` random indices into it."""
    return [(rng.random(size), rng.integers(0, size, max(gather_n, 1))) for size in tables]


def _time_gathers(arrays: list, best: list[float]) -> None:
    """Gather from each table three times (the first refills the cache), keeping in
    ``best`` the least CPU seconds per table."""
    for k, (table, idx) in enumerate(arrays):
        for _ in range(3):
            t = time.process_time()
            table.take(idx)
            best[k] = min(best[k], time.process_time() - t)


def timed_steps(scenario: str, cases: dict[str, dict], steps: int, warmup: int = 10,
                copies: int = 3, gather_n: int = 0, tables: tuple[int, ...] = (TABLE_ENTRIES,),
                block: int = 5, **shared) -> dict[str, float]:
    """CPU milliseconds per env step of ``scenario`` under each of ``cases`` (overrides by
    label, on top of ``shared``) with random actions, after ``warmup`` steps.

    Each case runs ``copies`` identical envs (same seed, same actions), stepped in turn
    at every step; the cases alternate in blocks of ``block`` steps, so all see the same
    machine load. Returns, per case label, the mean over steps of the fastest copy's
    time (``label``: brief contention from other processes slows one copy, not all)
    and the mean over every copy (``label + "_all"``); and ``"gather_us_<entries>"`` for
    each size in ``tables``: the least CPU microseconds of ``numpy.take`` of ``gather_n``
    float64 values at random indices of a table of that many entries, timed three
    times after every step (the fastest, cache-warm gather of the run; 0 when
    ``gather_n`` is 0).
    """
    rng = np.random.default_rng(0)
    envs: dict[str, list] = {}
    for label, overrides in cases.items():
        envs[label] = []
        for _ in range(copies):
            env = coop_loc_env.parallel_env(scenario, max_cycles=10**9, **shared, **overrides)
            env.reset(seed=0)
            envs[label].append(env)
    action_rngs = {label: np.random.default_rng(1) for label in cases}
    arrays = _gather_arrays(rng, gather_n, tables)
    best = [np.inf] * len(tables)
    fastest = dict.fromkeys(cases, 0.0)
    total = dict.fromkeys(cases, 0.0)

    def step(label: str, timed: bool) -> None:
        actions = None
        times = []
        for env in envs[label]:
            if not env.agents:
                env.reset()
            if actions is None:
                draw = action_rngs[label].uniform(-1, 1, (len(env.agents), 2))
                actions = dict(zip(env.agents, draw.astype(np.float32), strict=True))
            t = time.process_time()
            env.step(actions)
            times.append(time.process_time() - t)
        if timed:
            fastest[label] += min(times)
            total[label] += sum(times) / len(times)
            if gather_n:
                _time_gathers(arrays, best)

    for label in cases:
        for _ in range(warmup):
            step(label, False)
    done = 0
    while done < steps:
        n = min(block, steps - done)
        for label in cases:
            for _ in range(n):
                step(label, True)
        done += n
    out = {}
    for label in cases:
        out[label] = fastest[label] / steps * 1e3
        out[label + "_all"] = total[label] / steps * 1e3
    for size, b in zip(tables, best, strict=True):
        out[f"gather_us_{size}"] = b * 1e6 if gather_n else 0.0
    return out


def bench_mcl_team(steps: int = 60, training: bool = True, timesteps: int = 4096,
                   memory: bool = True, without_copies: bool = False,
                   calibrated_copies: bool = False) -> dict[str, float]:
    """The figures listed in the module docstring."""
    out: dict[str, float] = {}
    cfg = coop_loc_env.make_config("symmetric_hallway")
    n_values = cfg.n_robots * cfg.n_particles * cfg.sonar_beams
    cases: dict[str, dict] = {"mcl": {}}
    if without_copies:
        cases["no_copies"] = {"extras": {**cfg.extras, "mcl_symmetry_check": False}}
    if calibrated_copies:
        cases["calibrated"] = {"extras": {**cfg.extras, "mcl_calibrated_copies": True}}
    hall = timed_steps("symmetric_hallway", cases, steps, gather_n=n_values,
                       tables=(SMALL_TABLE_ENTRIES, TABLE_ENTRIES))
    gather = hall[f"gather_us_{SMALL_TABLE_ENTRIES}"]
    gather_big = hall[f"gather_us_{TABLE_ENTRIES}"]
    out["hallway_step_ms"] = hall["mcl"]
    out["hallway_gather_us"] = gather
    out["hallway_ratio"] = hall["mcl"] * 1e3 / gather
    out["hallway_ratio_all_copies"] = hall["mcl_all"] * 1e3 / gather
    out["hallway_gather_8mib_us"] = gather_big
    out["hallway_ratio_8mib"] = hall["mcl"] * 1e3 / gather_big
    if without_copies:
        out["hallway_step_ms_no_copies"] = hall["no_copies"]
        out["hallway_ratio_no_copies"] = hall["no_copies"] * 1e3 / gather
    if calibrated_copies:
        out["hallway_step_ms_calibrated"] = hall["calibrated"]
        out["hallway_ratio_calibrated"] = hall["calibrated"] * 1e3 / gather
    outdoor = {"n_robots": 4, "n_particles": 1000, "laser_beams": 30, "start_region": None,
               "extras": {**coop_loc_env.make_config("outdoor_terrain").extras,
                          "mcl": {"adaptive": False}}}
    paired = timed_steps("outdoor_terrain", {"ekf": {"estimator": "ekf"},
                                             "mcl": {"estimator": "mcl"}},
                         2 * steps, gather_n=30_000, **outdoor)
    ekf, mcl, g30 = paired["ekf"], paired["mcl"], paired[f"gather_us_{TABLE_ENTRIES}"]
    extra = (mcl - ekf) * 1e3 / 4
    out["outdoor_ekf_step_ms"] = ekf
    out["outdoor_mcl_step_ms"] = mcl
    out["outdoor_mcl_extra_us_per_robot"] = extra
    out["outdoor_gather_30k_us"] = g30
    out["outdoor_ratio"] = extra / g30
    out["outdoor_ratio_all_copies"] = (paired["mcl_all"] - paired["ekf_all"]) * 1e3 / 4 / g30
    if training:
        out["ppo_hallway_agent_steps_per_s"] = ppo_hallway_steps_per_second(timesteps)
    if memory:
        out.update(table_memory_mb())
        out.update(table_accuracy())
    return out


def table_memory_mb() -> dict[str, float]:
    """MB of the MCL lookup tables (range tables, beam-likelihood tables and likelihood
    fields) each shipped scenario builds, with ``estimator="mcl"`` for every scenario
    (the shipped MCL scenarios as they are), after a few steps; then their total."""
    from coop_loc_env.backends.mcl import MCLBackend
    from coop_loc_env.scenarios import list_scenarios

    out: dict[str, float] = {}
    seen: dict[int, int] = {}
    for name in list_scenarios():
        cfg = coop_loc_env.make_config(name)
        mcl = cfg.estimator == "mcl" or any(cfg.robot_spec(i).estimator == "mcl"
                                            for i in range(cfg.n_robots))
        env = coop_loc_env.parallel_env(name, **({} if mcl else {"estimator": "mcl"}))
        env.reset(seed=0)
        for _ in range(3):
            if env.agents:
                env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
        arrays: dict[int, int] = {}
        for backend in env.unwrapped.backends:
            if not isinstance(backend, MCLBackend):
                continue
            for pf in backend.filters:
                beam, fields = pf.cached_tables()
                for table, lut in beam:
                    for arr in (table.rows, table.free_cells, lut.table):
                        arrays[id(arr)] = arr.nbytes
                for lf in fields:
                    arrays[id(lf.table)] = lf.table.nbytes
        label = name if mcl else f"{name} (estimator=mcl)"
        out[f"tables_mb_{label}"] = sum(arrays.values()) / 2**20
        seen.update(arrays)
    out["tables_mb_total_distinct"] = sum(seen.values()) / 2**20
    return out


def table_accuracy(n: int = 20000) -> dict[str, float]:
    """Percentiles (m) of the range-table error against exact ray casts
    (:func:`estimators.mcl.beam_table.table_error`, ``n`` random free poses) for the beam-model
    maps of the shipped MCL scenarios."""
    from coop_loc_env.backends.mcl import MCLBackend
    from estimators.mcl.beam_table import table_error

    out: dict[str, float] = {}
    for name in ("symmetric_hallway", "hexagon"):
        env = coop_loc_env.parallel_env(name)
        env.reset(seed=0)
        for backend in env.unwrapped.backends:
            if not isinstance(backend, MCLBackend):
                continue
            done = set()
            for pf in backend.filters:
                for table, _ in pf.cached_tables()[0]:
                    sensor = "sonar" if table.rays_per_cone > 1 else "laser"
                    if sensor in done:
                        continue
                    done.add(sensor)
                    err = table_error(pf.grid, table, n)
                    for q in (50, 90, 99):
                        out[f"table_err_p{q}_m_{name}_{sensor}"] = float(np.percentile(err, q))
    return out


def ppo_hallway_steps_per_second(timesteps: int = 4096, seed: int = 0) -> float:
    """PPO agent steps per wall-clock second on ``symmetric_hallway`` (4 robots x 1000
    particles, 4 env copies in this process, ``scripts/bench/training.py``'s settings)."""
    path = Path(__file__).with_name("training.py")
    spec = importlib.util.spec_from_file_location("_bench_training", path)
    training = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(training)
    return training.ppo_steps_per_second(
        1, timesteps, seed, "symmetric_hallway",
        {"n_robots": 4, "n_particles": 1000, "max_cycles": 500})


def main(argv: list[str] | None = None) -> None:
    """Print :func:`bench_mcl_team`'s figures."""
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=60, help="timed env steps per case")
    parser.add_argument("--no-training", action="store_true", help="skip the PPO figure")
    parser.add_argument("--timesteps", type=int, default=4096, help="timed PPO agent steps")
    parser.add_argument("--no-memory", action="store_true",
                        help="skip the tables' sizes and accuracy")
    parser.add_argument("--without-copies", action="store_true",
                        help="also time the hallway without its kept symmetric copies "
                             "(mcl_symmetry_check=False), in alternating blocks of steps")
    parser.add_argument("--calibrated-copies", action="store_true",
                        help="also time the hallway with the kept copies sharing the weight "
                             "(mcl_calibrated_copies=True), in alternating blocks of steps")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.timesteps < 1:
        print(f"error: --steps and --timesteps must be >= 1, got {args.steps}, "
              f"{args.timesteps}", file=sys.stderr)
        sys.exit(2)
    figures = bench_mcl_team(args.steps, not args.no_training, args.timesteps,
                             not args.no_memory, args.without_copies,
                             args.calibrated_copies)
    for key, value in figures.items():
        print(f"{key:<50} {value:12.2f}")


if __name__ == "__main__":
    sys.exit(run_script(main))
