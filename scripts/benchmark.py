"""Benchmarks that print figures (not timed tests).

Env steps per second for teams of 4, 8, 20 and 50 robots (EKF, lasers on,
random actions), next to PettingZoo MPE ``simple_spread`` (package ``mpe2``)
at the same agent counts, with the ratio; plus the estimator micro-benchmarks
of the other modules (``scripts/_bench_*.py``) when present, among them the
multi-robot MCL step of ``symmetric_hallway`` over a bare gather
(``hallway_ratio``) and PPO agent steps per second on that hallway with 4
robots x 1000 particles (``ppo_hallway_agent_steps_per_s``, from
``scripts/_bench_mcl_team.py``).

    python scripts/benchmark.py [--seconds 3] [--sizes 4 8 20 50] [--json PATH]
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


def env_steps_per_second(n_robots: int, seconds: float, scenario: str = "outdoor_terrain",
                         read_camera: bool = False, **overrides) -> float:
    """Random-action env steps per second (CPU time of this process).

    Every robot stays in the episode (``tip_over_terminates=False``), so all
    ``n_robots`` are simulated, sensed and estimated at every step. The camera
    runs when its records are read; ``read_camera`` reads them at every step,
    as the scripted policies do.
    """
    kw = {"n_robots": n_robots, "max_cycles": 10**9, "estimator": "ekf",
          "tip_over_terminates": False}
    if scenario == "outdoor_terrain":
        kw["start_region"] = None  # spread a large team over the whole field
    kw.update(overrides)
    env = coop_loc_env.parallel_env(scenario, **kw)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    steps = 0
    start = time.process_time()
    while time.process_time() - start < seconds:
        if not env.agents:
            env.reset()
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        env.step(actions)
        if read_camera:
            for agent in env.agents:
                env.unwrapped.camera_readings(agent)
        steps += 1
    return steps / (time.process_time() - start)


def mpe_steps_per_second(n_agents: int, seconds: float) -> float | None:
    """``mpe2`` ``simple_spread`` steps per second with ``n_agents`` (None if not installed)."""
    try:
        from mpe2 import simple_spread_v3
    except ImportError:
        return None
    env = simple_spread_v3.parallel_env(N=n_agents, max_cycles=10**9, continuous_actions=True)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    steps = 0
    start = time.process_time()
    while time.process_time() - start < seconds:
        actions = {a: rng.uniform(0, 1, 5).astype(np.float32) for a in env.agents}
        env.step(actions)
        steps += 1
    return steps / (time.process_time() - start)


def _extra_benchmarks() -> dict[str, dict]:
    """Run ``scripts/_bench_*.py`` modules' ``bench_*()`` functions."""
    results = {}
    for path in sorted(Path(__file__).parent.glob("_bench_*.py")):
        spec = importlib.util.spec_from_file_location(path.stem, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[path.stem] = module
        spec.loader.exec_module(module)
        name = path.stem.removeprefix("_bench_")
        fn = getattr(module, f"bench_{name}", None)
        if fn is not None:
            print(f"\n== {name} ==", flush=True)
            results[name] = fn()
            for key, value in results[name].items():
                print(f"  {key:<45} {value:>14.4g}" if isinstance(value, float)
                      else f"  {key:<45} {value!s:>14}")
    return results


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=3.0, help="CPU seconds per measurement")
    parser.add_argument("--sizes", type=int, nargs="+", default=[4, 8, 20, 50])
    parser.add_argument("--json", type=Path, help="write the figures to this JSON file")
    parser.add_argument("--env-only", action="store_true", help="skip estimator benchmarks")
    args = parser.parse_args(argv)

    print("Env steps/s (CPU time; EKF, lasers on, random actions) vs mpe2 simple_spread")
    print(f"{'robots':>6} {'coop_loc':>10} {'mpe2':>10} {'ratio':>7} {'step ms':>8}")
    rows = []
    for n in args.sizes:
        ours = env_steps_per_second(n, args.seconds)
        mpe = mpe_steps_per_second(n, args.seconds)
        ratio = ours / mpe if mpe else float("nan")
        rows.append({"robots": n, "steps_per_s": ours, "mpe2_steps_per_s": mpe, "ratio": ratio})
        mpe_txt = f"{mpe:10.0f}" if mpe else f"{'n/a':>10}"
        print(f"{n:6d} {ours:10.0f} {mpe_txt} {ratio:7.2f} {1e3 / ours:8.3f}", flush=True)
    if len(rows) > 1:
        scale = rows[0]["steps_per_s"] / rows[-1]["steps_per_s"]
        print(f"step time at {rows[-1]['robots']} robots = {scale:.1f}x the step time at "
              f"{rows[0]['robots']} (target <= 15x)")
    n = args.sizes[0]
    with_camera = env_steps_per_second(n, args.seconds, read_camera=True)
    print(f"{n} robots with the camera's records read every step (as the scripted "
          f"policies do): {with_camera:.0f} steps/s, {1e3 / with_camera:.3f} ms/step")
    results = {"env": rows, "camera_read_every_step": {"robots": n, "steps_per_s": with_camera}}
    if not args.env_only:
        results.update(_extra_benchmarks())
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2, default=float))
    return results


if __name__ == "__main__":
    main()
