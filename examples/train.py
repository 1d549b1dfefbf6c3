"""Train one PPO policy shared by the whole team, briefly, and evaluate it against the FSM.

    python examples/train.py [--timesteps 4096] [--out runs/example_ppo]

A real run is much longer (see ``scripts/train.py --help`` and docs/learning.md);
this one takes about a minute on two cores and only shows the calls.
"""

from __future__ import annotations

import argparse

from policies.experiments.report import summarize
from policies.experiments.runner import run_episodes
from policies.learning.loader import load_learned_policy
from policies.learning.training import TrainConfig, train

ENV = {"n_robots": 2, "max_cycles": 100}  # evaluate with the same overrides as in training


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--timesteps", type=int, default=4096, help="agent steps to train")
    p.add_argument("--out", default="runs/example_ppo", help="output folder")
    args = p.parse_args(argv)
    cfg = TrainConfig(out=args.out, scenario="outdoor_terrain", estimator="ekf",
                      timesteps=args.timesteps, n_envs=2, n_steps=128, batch_size=128,
                      overrides=ENV, eval_freq=0, checkpoint_freq=0, progress_bar=False)
    summary = train(cfg)
    print(f"trained {summary['timesteps']} agent steps in {summary['wall_s']:.0f} s: "
          f"{summary['final_model']}")
    for policy in (load_learned_policy(args.out), "fsm"):
        figures = summarize(run_episodes("outdoor_terrain", policy, 2, seed=0, overrides=ENV,
                                         progress=False))
        name = policy if isinstance(policy, str) else "learned"
        print(f"{name:8s} team localization error "
              f"{figures['localization_error_m']['mean']:.3f} m")


if __name__ == "__main__":
    main()
