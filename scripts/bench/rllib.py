"""Benchmark of sampling throughput: RLlib env runners beside the stable-baselines3 path.

``bench_rllib()`` returns a flat ``dict[str, float]`` (``scripts/benchmark.py``
prints it; empty when Ray is not installed); run this file to print it standalone::

    python scripts/bench/rllib.py [--scenario outdoor_terrain] [--steps 600]

Agent steps (one per robot per env step) per wall-clock second of *sampling*
with the current, untrained policy acting (stochastic actions, one torch
thread per process), no learning:

* RLlib: PPO's env runners (:mod:`policies.learning.rllib_backend`) sampling ``--steps``
  env steps each, with 1 and 2 env-runner processes (local Ray, one CPU each);
  the figure for ``n`` runners is the total over all of them.
* stable-baselines3: the PPO policy and :class:`policies.learning.vec_env.ParallelEnvVecEnv`
  (2 env copies) stepped in this process and in 2 worker processes, the loop of
  SB3's rollout collection.
* the bare env with random actions, in this process, for reference.
"""

from __future__ import annotations

import time

import numpy as np

from coop_loc_env.cli import ScriptParser

N_ROBOTS = 3


def _env_config(scenario: str) -> dict:
    return {"scenario": scenario, "n_robots": N_ROBOTS, "estimator": "ekf"}


def bare_env_agent_steps_per_s(scenario: str, steps: int) -> float:
    """Random-action agent steps per wall second of the bare env (auto-reset)."""
    import coop_loc_env

    env = coop_loc_env.parallel_env(**_env_config(scenario))
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    agent_steps, start = 0, time.perf_counter()
    for _ in range(steps):
        if not env.agents:
            env.reset()
        agent_steps += len(env.agents)
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
    return agent_steps / (time.perf_counter() - start)


def sb3_agent_steps_per_s(scenario: str, steps: int, n_procs: int) -> float:
    """Agent steps per wall second of the SB3 rollout loop (policy + ``ParallelEnvVecEnv``)."""
    import torch
    from stable_baselines3 import PPO

    from policies.learning.vec_env import ParallelEnvVecEnv, make_env_fn

    torch.set_num_threads(1)
    cfg = _env_config(scenario)
    venv = ParallelEnvVecEnv(make_env_fn(cfg.pop("scenario"), **cfg), n_envs=2, n_procs=n_procs)
    try:
        model = PPO("MlpPolicy", venv, device="cpu", seed=0)
        obs = venv.reset()
        for _ in range(20):  # warm-up
            obs = venv.step(model.predict(obs)[0])[0]
        start = time.perf_counter()
        for _ in range(steps):
            obs = venv.step(model.predict(obs)[0])[0]
        return steps * venv.num_envs / (time.perf_counter() - start)
    finally:
        venv.close()


def rllib_agent_steps_per_s(scenario: str, steps: int, num_env_runners: int) -> float:
    """Agent steps per wall second of RLlib PPO sampling with ``num_env_runners`` processes."""
    import ray

    from policies.learning.rllib_backend import ppo_config

    ray.init(address="local", num_cpus=num_env_runners + 1, include_dashboard=False,
             log_to_driver=False, configure_logging=False)
    try:
        algo = ppo_config(_env_config(scenario), num_env_runners=num_env_runners).build_algo()
        group = algo.env_runner_group

        def sample(n: int) -> int:
            episodes = group.foreach_env_runner(
                lambda runner: sum(ep.agent_steps() for ep in runner.sample(num_timesteps=n)),
                local_env_runner=False,
            )
            return int(sum(episodes))

        sample(20)  # warm-up
        start = time.perf_counter()
        agent_steps = sample(steps)
        wall = time.perf_counter() - start
        algo.stop()
        return agent_steps / wall
    finally:
        ray.shutdown()


def bench_rllib(scenario: str = "outdoor_terrain", steps: int = 600) -> dict[str, float]:
    """RLlib sampling with 1 and 2 env runners, the SB3 path with 1 and 2 processes."""
    try:
        import ray  # noqa: F401
    except ImportError:
        print("  (ray not installed: pip install -e '.[rllib]')")
        return {}
    out = {"bare_env_agent_steps_per_s": bare_env_agent_steps_per_s(scenario, steps)}
    for n in (1, 2):
        out[f"sb3_agent_steps_per_s_{n}proc"] = sb3_agent_steps_per_s(scenario, steps // 2, n)
    for n in (1, 2):
        out[f"rllib_agent_steps_per_s_{n}runner"] = rllib_agent_steps_per_s(scenario, steps, n)
    out["rllib_speedup_2_vs_1_runner"] = (
        out["rllib_agent_steps_per_s_2runner"] / out["rllib_agent_steps_per_s_1runner"]
    )
    out["sb3_speedup_2_vs_1_proc"] = out["sb3_agent_steps_per_s_2proc"] / out[
        "sb3_agent_steps_per_s_1proc"]
    return out


if __name__ == "__main__":
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="outdoor_terrain")
    parser.add_argument("--steps", type=int, default=600, help="env steps per runner")
    args = parser.parse_args()
    for key, value in bench_rllib(args.scenario, args.steps).items():
        print(f"  {key:<45} {value:>14.4g}")
