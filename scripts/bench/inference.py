"""Benchmark of learned-policy inference: one team observation per call, torch thread counts.

Evaluating a policy asks the network for one small batch (one observation per
robot) per env step. Such a forward pass is too small to gain from torch's
intra-op threads, which by default number the machine's cores; they only add
synchronization. This script times ``model.predict`` on one team observation
with torch's default thread count and with one thread, in one run, and prints
both and their ratio::

    python scripts/bench/inference.py [--calls 2000] [--model PATH.zip]

Without ``--model`` it builds an untrained PPO ``MlpPolicy`` (64x64, the
training default) for ``outdoor_terrain`` with 3 robots: the cost of a forward
pass does not depend on the weights.
"""

from __future__ import annotations

import time

from coop_loc_env.cli import ScriptParser, run_script


def predict_ms(model, batch, calls: int) -> float:
    """Median over 5 repeats of the mean milliseconds per ``model.predict(batch)``."""
    runs = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(calls):
            model.predict(batch, deterministic=True)
        runs.append(1e3 * (time.perf_counter() - t0) / calls)
    return sorted(runs)[2]


def main(argv: list[str] | None = None) -> int:
    """Print ms per call with the default and with one torch thread."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--calls", type=int, default=2000, help="predict calls per repeat")
    p.add_argument("--model", default=None, help="a saved SB3 model (.zip) to time instead")
    args = p.parse_args(argv)
    import numpy as np
    import torch
    from stable_baselines3 import PPO

    import coop_loc_env
    from policies.learning.learned import SB3Policy

    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=3)
    obs, _ = env.reset(seed=0)
    if args.model:
        model = SB3Policy(args.model).model
    else:
        from policies.learning.vec_env import ParallelEnvVecEnv, make_env_fn

        venv = ParallelEnvVecEnv(make_env_fn("outdoor_terrain", n_robots=3), n_envs=1)
        model = PPO("MlpPolicy", venv, n_steps=64, device="cpu", seed=0)
        venv.close()
    batch = np.stack(list(obs.values()))
    default = torch.get_num_threads()
    model.predict(batch, deterministic=True)  # warm up
    t_default = predict_ms(model, batch, args.calls)
    torch.set_num_threads(1)
    t_one = predict_ms(model, batch, args.calls)
    print(f"torch threads {default} (default): {t_default:.3f} ms per predict")
    print(f"torch threads 1: {t_one:.3f} ms per predict")
    print(f"ratio default / one thread: {t_default / t_one:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
