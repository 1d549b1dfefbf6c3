"""Env throughput with the MCL backend: 4 robots x 1000 particles.

``bench_mcl_env()`` returns env steps per second (process CPU time, random
actions) for

* ``outdoor_terrain`` with ``estimator="mcl"`` (laser likelihood field, DGPS,
  compass; position tracking, so KLD-sampling may shrink the sets below 1000),
* ``symmetric_hallway`` with 4 sonar robots in global localization (beam model
  with range-table lookups; sets stay near 1000 while the robots are lost),
* ``hexagon`` with 2 sonar and 2 laser robots in global localization,

each with a fixed particle count (``adaptive`` off) as well, so the figure is
for exactly 1000 particles per robot. ``scripts/benchmark.py``
imports it; ``python scripts/bench/mcl_env.py`` prints it.
"""

from __future__ import annotations

import sys
import time

import numpy as np

import coop_loc_env
from coop_loc_env.cli import ScriptParser, run_script

__all__ = ["bench_mcl_env"]

CASES = {
    "outdoor_terrain": {"start_region": None},
    "symmetric_hallway": {},
    "hexagon": {},
}


def _steps_per_second(scenario: str, seconds: float, fixed: bool, **overrides) -> float:
    kw = {"n_robots": 4, "estimator": "mcl", "n_particles": 1000, "max_cycles": 10**9}
    kw.update(overrides)
    if fixed:
        kw["extras"] = {**coop_loc_env.make_config(scenario).extras, "mcl": {"adaptive": False}}
    env = coop_loc_env.parallel_env(scenario, **kw)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(3):  # warm-up (table building)
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
    steps = 0
    start = time.process_time()
    while time.process_time() - start < seconds:
        if not env.agents:
            env.reset()
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        steps += 1
    return steps / (time.process_time() - start)


def bench_mcl_env(seconds: float = 3.0) -> dict[str, float]:
    """Env steps per second with 4 MCL robots x 1000 particles, per scenario."""
    out = {}
    for scenario, overrides in CASES.items():
        out[f"{scenario}_4x1000_fixed_steps_per_s"] = _steps_per_second(
            scenario, seconds, True, **overrides
        )
        out[f"{scenario}_4x1000_adaptive_steps_per_s"] = _steps_per_second(
            scenario, seconds, False, **overrides
        )
    return out


def main(argv: list[str] | None = None) -> None:
    """Print :func:`bench_mcl_env`'s figures."""
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0,
                        help="CPU seconds per measurement")
    args = parser.parse_args(argv)
    if not args.seconds > 0:
        print(f"error: --seconds must be > 0, got {args.seconds}", file=sys.stderr)
        sys.exit(2)
    for key, value in bench_mcl_env(args.seconds).items():
        print(f"{key:<50} {value:10.1f}")


if __name__ == "__main__":
    sys.exit(run_script(main))
