"""Env steps per second with the centralized team MLE (``estimator="mle"``), 4 and 20 robots.

``bench_mle_env()`` returns a flat ``dict[str, float]`` (``scripts/benchmark.py``
prints it); run this file to print it standalone::

    OPENBLAS_NUM_THREADS=1 python scripts/bench/mle_env.py [--seconds 3]

Measured on two scenarios with random actions, after a warm-up of
``warmup_steps`` steps so that the MLE's sliding window is full:

* ``dispersal`` (Howard et al.'s sensors: odometry and a 10 Hz robot detector,
  laser scans; robots start crowded in one room, and under random actions they
  stay crowded: every robot sees several teammates, the worst case for the MLE),
  with the EKF on the same scenario for reference;
* ``outdoor_terrain`` spread over the whole field (the env benchmark's
  setting) with ``estimator="mle"``.

Figures are CPU time of this process (``time.process_time``).
"""

from __future__ import annotations

import time

import numpy as np

import coop_loc_env
from coop_loc_env.cli import ScriptParser


def mle_env_steps_per_second(
    scenario: str, n_robots: int, seconds: float, warmup_steps: int = 150, **overrides
) -> float:
    """Random-action env steps per CPU second after ``warmup_steps`` steps."""
    kw = {"n_robots": n_robots, "max_cycles": 10**9, "estimator": "mle"}
    if scenario == "outdoor_terrain":
        kw["start_region"] = None
    kw.update(overrides)
    env = coop_loc_env.parallel_env(scenario, **kw)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step() -> None:
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        env.step(actions)

    for _ in range(warmup_steps):
        step()
    steps = 0
    start = time.process_time()
    while time.process_time() - start < seconds:
        step()
        steps += 1
    return steps / (time.process_time() - start)


def bench_mle_env(seconds: float = 3.0) -> dict[str, float]:
    """Env steps/s with ``estimator="mle"`` at 4 and 20 robots (see the module docstring)."""
    out: dict[str, float] = {}
    for n in (4, 20):
        out[f"dispersal_mle_{n}_steps_per_s"] = mle_env_steps_per_second("dispersal", n, seconds)
    out["dispersal_ekf_20_steps_per_s"] = mle_env_steps_per_second(
        "dispersal", 20, seconds, estimator="ekf"
    )
    for n in (4, 20):
        out[f"outdoor_mle_{n}_steps_per_s"] = mle_env_steps_per_second(
            "outdoor_terrain", n, seconds
        )
    return out


if __name__ == "__main__":
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=3.0, help="CPU seconds per measurement")
    args = p.parse_args()
    for key, value in bench_mle_env(args.seconds).items():
        print(f"{key:<40} {value:10.1f}")
