"""Team MCL cost per env step against a bare numpy gather, and PPO throughput with MCL.

``bench_mcl_team()`` returns, measured in one run with the process CPU clock
(``time.process_time``, so time spent descheduled on a shared machine does not
count):

* ``hallway_step_ms``: one ``symmetric_hallway`` env step as shipped (8 sonar
  robots, up to 2000 particles each, 16 beams, detections on; random actions,
  after a warm-up that builds the tables and lets KLD-sampling settle);
* ``hallway_gather_us``: ``numpy.take`` of robots x particles x beams
  (8 x 2000 x 16 = 256,000) float64 values at random indices of a
  2**20-entry table (8 MiB, the size class of a map's lookup table), and
  ``hallway_ratio``, the step over the gather;
* ``outdoor_mcl_extra_us_per_robot``: in ``outdoor_terrain`` with 4 robots,
  1000 particles and 30 laser beams, the CPU time per robot and step that
  ``estimator="mcl"`` adds over ``estimator="ekf"`` (fixed particle count), and
  ``outdoor_ratio``, that over a 30,000-value gather of the same kind;
* with ``training=True``, ``ppo_hallway_agent_steps_per_s``: PPO agent steps
  per wall-clock second on ``symmetric_hallway`` with 4 robots and 1000
  particles (:func:`scripts._bench_training`'s settings otherwise).

Run ``python scripts/_bench_mcl_team.py --help`` for the options.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import coop_loc_env

__all__ = ["bench_mcl_team", "gather_us", "step_ms"]

TABLE_ENTRIES = 2**20


def gather_us(n: int, repeat: int = 50, seed: int = 0) -> float:
    """CPU microseconds of ``numpy.take`` of ``n`` random float64 values of a 2**20-entry table
    (best of ``repeat``)."""
    rng = np.random.default_rng(seed)
    table = rng.random(TABLE_ENTRIES)
    idx = rng.integers(0, TABLE_ENTRIES, n)
    best = np.inf
    for _ in range(repeat):
        t = time.process_time()
        table.take(idx)
        best = min(best, time.process_time() - t)
    return best * 1e6


def step_ms(scenario: str, steps: int, warmup: int = 10, **overrides) -> float:
    """Mean CPU milliseconds per env step with random actions (after ``warmup`` steps)."""
    env = coop_loc_env.parallel_env(scenario, max_cycles=10**9, **overrides)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def one() -> None:
        if not env.agents:
            env.reset()
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})

    for _ in range(warmup):
        one()
    start = time.process_time()
    for _ in range(steps):
        one()
    return (time.process_time() - start) / steps * 1e3


def bench_mcl_team(steps: int = 60, training: bool = True, timesteps: int = 4096
                   ) -> dict[str, float]:
    """The figures listed in the module docstring."""
    out: dict[str, float] = {}
    cfg = coop_loc_env.make_config("symmetric_hallway")
    n_values = cfg.n_robots * cfg.n_particles * cfg.sonar_beams
    g0 = gather_us(n_values)
    hall = step_ms("symmetric_hallway", steps)
    g1 = gather_us(n_values)
    out["hallway_step_ms"] = hall
    out["hallway_gather_us"] = min(g0, g1)
    out["hallway_ratio"] = hall * 1e3 / out["hallway_gather_us"]
    outdoor = {"n_robots": 4, "n_particles": 1000, "laser_beams": 30, "start_region": None,
               "extras": {**coop_loc_env.make_config("outdoor_terrain").extras,
                          "mcl": {"adaptive": False}}}
    ekf = step_ms("outdoor_terrain", steps, estimator="ekf", **outdoor)
    mcl = step_ms("outdoor_terrain", steps, estimator="mcl", **outdoor)
    g30 = gather_us(30_000)
    extra = (mcl - ekf) * 1e3 / 4
    out["outdoor_ekf_step_ms"] = ekf
    out["outdoor_mcl_step_ms"] = mcl
    out["outdoor_mcl_extra_us_per_robot"] = extra
    out["outdoor_gather_30k_us"] = g30
    out["outdoor_ratio"] = extra / g30
    if training:
        out["ppo_hallway_agent_steps_per_s"] = ppo_hallway_steps_per_second(timesteps)
    return out


def ppo_hallway_steps_per_second(timesteps: int = 4096, seed: int = 0) -> float:
    """PPO agent steps per wall-clock second on ``symmetric_hallway`` (4 robots x 1000
    particles, 4 env copies in this process, :mod:`scripts._bench_training`'s settings)."""
    import torch
    from stable_baselines3 import PPO

    from policies.vec_env import ParallelEnvVecEnv, make_env_fn

    torch.set_num_threads(1)
    venv = ParallelEnvVecEnv(
        make_env_fn("symmetric_hallway", n_robots=4, n_particles=1000, max_cycles=500),
        n_envs=4, n_procs=1,
    )
    try:
        model = PPO("MlpPolicy", venv, n_steps=128, batch_size=256, n_epochs=5, seed=seed,
                    device="cpu", verbose=0)
        model.learn(total_timesteps=128 * venv.num_envs)  # warm-up rollout and update
        start_steps = model.num_timesteps
        start = time.perf_counter()
        model.learn(total_timesteps=timesteps, reset_num_timesteps=False)
        return (model.num_timesteps - start_steps) / (time.perf_counter() - start)
    finally:
        venv.close()


def main(argv: list[str] | None = None) -> None:
    """Print :func:`bench_mcl_team`'s figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=60, help="timed env steps per case")
    parser.add_argument("--no-training", action="store_true", help="skip the PPO figure")
    parser.add_argument("--timesteps", type=int, default=4096, help="timed PPO agent steps")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.timesteps < 1:
        print(f"error: --steps and --timesteps must be >= 1, got {args.steps}, "
              f"{args.timesteps}", file=sys.stderr)
        sys.exit(2)
    for key, value in bench_mcl_team(args.steps, not args.no_training, args.timesteps).items():
        print(f"{key:<35} {value:12.2f}")


if __name__ == "__main__":
    main()
