"""Benchmark of PPO training throughput: env steps per second with 1 and 2 processes.

``bench_training()`` returns a flat ``dict[str, float]`` (``scripts/benchmark.py``
prints it); run this file to print it standalone::

    python scripts/bench/training.py [--timesteps 6144]

PPO (``MlpPolicy`` 64x64, ``n_steps=128``, batch 256, 5 epochs, one torch
thread) on ``outdoor_terrain`` (3 robots, EKF) through
:class:`policies.learning.vec_env.ParallelEnvVecEnv` with 4 env copies (12 agent
slots), stepped in this process (``n_procs=1``) or in 2 worker processes.
Throughput is agent steps (SB3 timesteps) per wall-clock second over
``model.learn`` after one warm-up rollout, rollout collection and gradient
updates included; ``team_steps_per_s`` divides by the 3 robots (parallel-env
steps per second).
"""

from __future__ import annotations

import sys
import time

from coop_loc_env.cli import ScriptParser, run_script

N_ENVS = 4
N_ROBOTS = 3


OUTDOOR = {"estimator": "ekf", "n_robots": N_ROBOTS, "max_cycles": 500}


def ppo_steps_per_second(n_procs: int, timesteps: int = 6144, seed: int = 0,
                         scenario: str = "outdoor_terrain", overrides: dict | None = None
                         ) -> float:
    """Agent steps per wall-clock second of PPO training with ``n_procs`` processes on
    ``N_ENVS`` copies of ``scenario`` (``overrides``, by default :data:`OUTDOOR`)."""
    import torch
    from stable_baselines3 import PPO

    from policies.learning.vec_env import ParallelEnvVecEnv, make_env_fn

    torch.set_num_threads(1)
    venv = ParallelEnvVecEnv(
        make_env_fn(scenario, **(OUTDOOR if overrides is None else overrides)),
        n_envs=N_ENVS, n_procs=n_procs,
    )
    try:
        model = PPO("MlpPolicy", venv, n_steps=128, batch_size=256, n_epochs=5, seed=seed,
                    device="cpu", verbose=0)
        model.learn(total_timesteps=128 * venv.num_envs)  # warm-up rollout and update
        start_steps = model.num_timesteps
        start = time.perf_counter()
        model.learn(total_timesteps=timesteps, reset_num_timesteps=False)
        wall = time.perf_counter() - start
        return (model.num_timesteps - start_steps) / wall
    finally:
        venv.close()


def bench_training(timesteps: int = 6144) -> dict[str, float]:
    """PPO training throughput with 1 and 2 processes, and the speed-up."""
    one = ppo_steps_per_second(1, timesteps)
    two = ppo_steps_per_second(2, timesteps)
    return {
        "ppo_agent_steps_per_s_1proc": one,
        "ppo_agent_steps_per_s_2procs": two,
        "ppo_team_steps_per_s_1proc": one / N_ROBOTS,
        "ppo_team_steps_per_s_2procs": two / N_ROBOTS,
        "speedup_2procs_vs_1": two / one,
    }


def main() -> None:
    """Print :func:`bench_training`'s figures."""
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--timesteps", type=int, default=6144)
    args = parser.parse_args()
    for key, value in bench_training(args.timesteps).items():
        print(f"{key:<35} {value:10.1f}")


if __name__ == "__main__":
    sys.exit(run_script(main))
