"""Benchmarks that print figures (not timed tests).

Env steps per second for teams of 4, 8, 20 and 50 robots (``outdoor_terrain``,
EKF, lasers on, random actions), next to PettingZoo MPE ``simple_spread``
(package ``mpe2``, continuous actions) at the same agent counts, both in this
process and alternating in short slices of CPU time, over a few rounds; the
ratio (env / mpe2 steps per second) of each round, the ratio at the smallest
team against its target (>= 1.5, at least 1.1) and how much longer the step of
the largest team takes (target <= 6x; the two teams alternating likewise); plus
the micro-benchmarks of the modules of ``scripts/bench/`` (each ``NAME.py`` that
defines ``bench_NAME()``), among them the multi-robot MCL step of
``symmetric_hallway`` over a bare gather (``hallway_ratio``) and PPO agent steps
per second on that hallway with 4 robots x 1000 particles (``ppo_hallway_agent_steps_per_s``, from
``scripts/bench/mcl_team.py``).

    python scripts/benchmark.py [--seconds 1] [--rounds 3] [--sizes 4 8 20 50] [--json PATH]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

import coop_loc_env
from coop_loc_env.cli import ScriptParser, run_script

#: Targets the benchmark reports against: env / mpe2 steps per second at the smallest
#: team (the goal, and the least acceptable), and the step time of the largest team
#: over that of the smallest.
RATIO_TARGET, RATIO_FLOOR, GROWTH_TARGET = 1.5, 1.1, 6.0
_SLICE = 0.05  # CPU seconds of one side before the other runs


class _Stepper:
    """Random-action steps of one parallel env, timed in CPU time of this process."""

    def __init__(self, env, low: float, dims: int) -> None:
        self.env, self.low, self.dims = env, low, dims
        self.rng = np.random.default_rng(0)
        env.reset(seed=0)

    def run(self, seconds: float, read_camera: bool = False) -> tuple[int, float]:
        """Step for about ``seconds`` of CPU time; returns (steps, CPU seconds)."""
        env, rng = self.env, self.rng
        steps = 0
        start = time.process_time()
        while time.process_time() - start < seconds:
            if not env.agents:
                env.reset()
            env.step({a: rng.uniform(self.low, 1, self.dims).astype(np.float32)
                      for a in env.agents})
            if read_camera:
                for agent in env.agents:
                    env.unwrapped.camera_readings(agent)
            steps += 1
        return steps, time.process_time() - start


def _env_stepper(n_robots: int, scenario: str = "outdoor_terrain", **overrides) -> _Stepper:
    kw = {"n_robots": n_robots, "max_cycles": 10**9, "estimator": "ekf",
          "tip_over_terminates": False}
    if scenario == "outdoor_terrain":
        kw["start_region"] = None  # spread a large team over the whole field
    kw.update(overrides)
    return _Stepper(coop_loc_env.parallel_env(scenario, **kw), -1.0, 2)


def _mpe_stepper(n_agents: int) -> _Stepper | None:
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return None
    env = simple_spread_v3.parallel_env(N=n_agents, max_cycles=10**9, continuous_actions=True)
    return _Stepper(env, 0.0, 5)


def env_steps_per_second(n_robots: int, seconds: float, scenario: str = "outdoor_terrain",
                         read_camera: bool = False, **overrides) -> float:
    """Random-action env steps per second (CPU time of this process).

    Every robot stays in the episode (``tip_over_terminates=False``), so all
    ``n_robots`` are simulated, sensed and estimated at every step. The camera
    runs when its records are read; ``read_camera`` reads them at every step,
    as the scripted policies do.
    """
    steps, cpu = _env_stepper(n_robots, scenario, **overrides).run(seconds, read_camera)
    return steps / cpu


def mpe_steps_per_second(n_agents: int, seconds: float) -> float | None:
    """``mpe2`` ``simple_spread`` steps per second with ``n_agents`` (None if not installed)."""
    stepper = _mpe_stepper(n_agents)
    if stepper is None:
        return None
    steps, cpu = stepper.run(seconds)
    return steps / cpu


def interleaved_rounds(n: int, seconds: float, rounds: int) -> list[dict]:
    """Env and mpe2 steps per second with ``n`` agents, ``rounds`` times.

    In each round both run for ``seconds`` of CPU time, alternating in slices of
    :data:`_SLICE` s, so that both see the same load of the machine; each round
    gives ``steps_per_s``, ``mpe2_steps_per_s`` (None without mpe2) and ``ratio``.
    """
    ours, theirs = _env_stepper(n), _mpe_stepper(n)
    ours.run(min(0.3, seconds))  # warm-up: first steps, compiled code, caches
    if theirs is not None:
        theirs.run(min(0.3, seconds))
    out = []
    for _ in range(rounds):
        done = {"ours": [0, 0.0], "theirs": [0, 0.0]}
        while done["ours"][1] < seconds:
            for key, stepper in (("ours", ours), ("theirs", theirs)):
                if stepper is not None:
                    steps, cpu = stepper.run(_SLICE)
                    done[key][0] += steps
                    done[key][1] += cpu
        rate = done["ours"][0] / done["ours"][1]
        mpe = done["theirs"][0] / done["theirs"][1] if theirs is not None else None
        out.append({"steps_per_s": rate, "mpe2_steps_per_s": mpe,
                    "ratio": rate / mpe if mpe else float("nan")})
    return out


def growth_rounds(small: int, large: int, seconds: float, rounds: int) -> list[float]:
    """Step time of ``large`` robots over that of ``small``, ``rounds`` times, the two
    teams alternating in slices of :data:`_SLICE` s (``seconds`` of CPU time each per
    round), so that both see the same load of the machine."""
    a, b = _env_stepper(small), _env_stepper(large)
    a.run(min(0.3, seconds))
    b.run(min(0.3, seconds))
    out = []
    for _ in range(rounds):
        done = {"a": [0, 0.0], "b": [0, 0.0]}
        while done["a"][1] < seconds:
            for key, stepper in (("a", a), ("b", b)):
                steps, cpu = stepper.run(_SLICE)
                done[key][0] += steps
                done[key][1] += cpu
        out.append((done["b"][1] / done["b"][0]) / (done["a"][1] / done["a"][0]))
    return out


def _span(values: list[float], fmt: str) -> str:
    lo, hi = min(values), max(values)
    return format(lo, fmt) if format(lo, fmt) == format(hi, fmt) else (
        f"{format(lo, fmt)}-{format(hi, fmt)}")


def _extra_benchmarks() -> dict[str, dict]:
    """Run the ``bench_NAME()`` function of each ``scripts/bench/NAME.py`` that has one."""
    results = {}
    for path in sorted((Path(__file__).parent / "bench").glob("*.py")):
        name = path.stem
        if f"def bench_{name}(" not in path.read_text():
            continue
        module_name = f"_bench_{name}"  # not NAME, which may be a package's name (torchrl)
        spec = importlib.util.spec_from_file_location(module_name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module
        spec.loader.exec_module(module)
        fn = getattr(module, f"bench_{name}", None)
        if fn is not None:
            print(f"\n== {name} ==", flush=True)
            results[name] = fn()
            for key, value in results[name].items():
                print(f"  {key:<45} {value:>14.4g}" if isinstance(value, float)
                      else f"  {key:<45} {value!s:>14}")
    return results


def _bad_argument(args: argparse.Namespace) -> str | None:
    """What is wrong with the arguments, or None."""
    if not args.seconds > 0:
        return f"--seconds must be positive, got {args.seconds}"
    if args.rounds < 1:
        return f"--rounds must be at least 1, got {args.rounds}"
    if any(n < 1 for n in args.sizes):
        return f"--sizes must be positive robot counts, got {args.sizes}"
    return None


def main(argv: list[str] | None = None) -> dict | int:
    """Print the figures; returns them (2 on bad arguments, after one line on stderr)."""
    parser = ScriptParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=1.0,
                        help="CPU seconds of each side (env, mpe2) per round")
    parser.add_argument("--rounds", type=int, default=3, help="rounds per team size")
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 20, 50])
    parser.add_argument("--json", type=Path, help="write the figures to this JSON file")
    parser.add_argument("--env-only", action="store_true", help="skip estimator benchmarks")
    args = parser.parse_args(argv)
    bad = _bad_argument(args)
    if bad:
        print(f"error: {bad}", file=sys.stderr)
        return 2

    print("Env steps/s (CPU time; outdoor_terrain, EKF, lasers on, random actions) vs mpe2 "
          f"simple_spread, alternating in one process, {args.rounds} rounds")
    print(f"{'robots':>6} {'coop_loc':>11} {'mpe2':>11} {'ratio':>11} {'step ms':>11}")
    rows = []
    for n in args.sizes:
        per_round = interleaved_rounds(n, args.seconds, args.rounds)
        rates = [r["steps_per_s"] for r in per_round]
        mpes = [r["mpe2_steps_per_s"] for r in per_round if r["mpe2_steps_per_s"]]
        ratios = [r["ratio"] for r in per_round if r["mpe2_steps_per_s"]]
        rows.append({"robots": n, "steps_per_s": float(np.median(rates)),
                     "mpe2_steps_per_s": float(np.median(mpes)) if mpes else None,
                     "ratio": float(np.median(ratios)) if ratios else float("nan"),
                     "rounds": per_round})
        mpe_txt = _span(mpes, ".0f") if mpes else "n/a"
        ratio_txt = _span(ratios, ".2f") if ratios else "n/a"
        ms = [1e3 / r for r in rates]
        print(f"{n:6d} {_span(rates, '.0f'):>11} {mpe_txt:>11} {ratio_txt:>11} "
              f"{_span(ms, '.3f'):>11}", flush=True)
    first = rows[0]
    if first["mpe2_steps_per_s"]:
        verdict = ("meets the target" if first["ratio"] >= RATIO_TARGET else
                   "short of the target, above the floor" if first["ratio"] >= RATIO_FLOOR
                   else "below the floor")
        print(f"ratio to mpe2 at {first['robots']} robots: {first['ratio']:.2f} (median of the "
              f"rounds; target >= {RATIO_TARGET}, at least {RATIO_FLOOR}): {verdict}")
    growth = None
    if len(rows) > 1:
        per_round = growth_rounds(first["robots"], rows[-1]["robots"], args.seconds,
                                  args.rounds)
        growth = float(np.median(per_round))
        print(f"step time at {rows[-1]['robots']} robots = {growth:.1f}x the step time at "
              f"{first['robots']} (median of {args.rounds} rounds alternating the two teams, "
              f"{_span(per_round, '.1f')}; target <= {GROWTH_TARGET:g}x)")
    n = args.sizes[0]
    with_camera = env_steps_per_second(n, args.seconds, read_camera=True)
    print(f"{n} robots with the camera's records read every step (as the scripted "
          f"policies do): {with_camera:.0f} steps/s, {1e3 / with_camera:.3f} ms/step")
    results = {"env": rows, "growth": growth, "growth_rounds": per_round if growth else None,
               "camera_read_every_step": {"robots": n, "steps_per_s": with_camera}}
    if not args.env_only:
        results.update(_extra_benchmarks())
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2, default=float))
    return results


if __name__ == "__main__":
    result = run_script(main)
    sys.exit(result if isinstance(result, int) else 0)
