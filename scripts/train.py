"""Train one policy shared by all robots of a team (PPO by default, or SAC) with stable-baselines3.

Examples::

    python scripts/train.py --scenario outdoor_terrain --estimator ekf --timesteps 300000 \\
        --n-envs 4 --n-procs 2 --seed 0 --out runs/ppo_outdoor \\
        --reward-localization-weight 5 --reward-coverage-weight 1
    python scripts/train.py --out runs/ppo_outdoor --resume runs/ppo_outdoor --timesteps 100000
    python scripts/evaluate.py --policy runs/ppo_outdoor/final_model.zip --episodes 20
    python scripts/train.py --backend rllib --num-env-runners 2 --timesteps 40000 --out runs/rl
    python scripts/evaluate.py --policy runs/rl --episodes 3
    python scripts/train.py --config examples/configs/mixed_team.yaml --timesteps 20000 \\
        --out runs/mixed

``--config FILE.yaml`` holds the scenario, any scenario config key and the team
(see docs/configs.md); ``--set`` and the options given apply on top of it.

A scenario may carry its own training defaults (``rendezvous`` does: its
reward, observation and PPO settings, see ``coop_loc_env/scenarios/rendezvous.py``);
options given on the command line override them.

Writes ``DIR/final_model.zip`` (loadable by ``scripts/evaluate.py --policy``),
``DIR/checkpoints/``, TensorBoard logs in ``DIR/tb`` (``tensorboard --logdir DIR/tb``;
periodic evaluation against the FSM baseline under ``eval/`` and ``baseline/``),
``DIR/train_config.json`` and ``DIR/train_summary.json``. ``--timesteps`` counts
agent steps (one per robot per env step). Evaluate with the same ``--set``
overrides as in training (the observation size depends on some of them).

``--backend rllib`` trains the same shared policy with Ray RLlib's PPO
(``--num-env-runners N`` sampling processes, ``--address`` of a Ray cluster;
see docs/scaling.md) and writes the checkpoint ``DIR/checkpoint``, TensorBoard
logs in ``DIR/tb``, ``DIR/train_config.json`` and ``DIR/train_summary.json``.
``scripts/evaluate.py --policy DIR`` evaluates either kind of run.

Torch runs on the project's thread count (one thread; ``COOP_LOC_TORCH_THREADS=N``
overrides it, ``0`` leaves torch's default: see docs/scaling.md).
"""

from __future__ import annotations

import argparse
import os
import sys

from coop_loc_env.cli import (
    ScriptParser,
    add_config_arguments,
    require,
    run_script,
    scenario_and_overrides,
)
from policies.learning.training import (
    ALGOS,
    VEC_ENVS,
    TrainConfig,
    estimate_cloning_s,
    train,
    trained_timesteps,
)
from policies.learning.vec_env import REWARD_MODES
from policies.scripted.registry import policy_names


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface."""
    d = TrainConfig(out="")
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    add_config_arguments(p, d.scenario)
    p.add_argument("--estimator", default=None, help="ekf | mcl | mle (scenario default if unset)")
    p.add_argument("--algo", default=d.algo, type=str.upper, choices=ALGOS, help="PPO or SAC")
    p.add_argument("--timesteps", type=int, default=d.timesteps, help="agent steps to train")
    p.add_argument("--n-envs", type=int, default=d.n_envs, help="env copies (each gives one "
                   "slot per robot)")
    p.add_argument("--n-procs", type=int, default=d.n_procs, help="processes stepping the "
                   "copies (1 = this process)")
    p.add_argument("--vec-env", default=d.vec_env, choices=VEC_ENVS, help="auto: one "
                   "batched env when --n-procs is 1 and the env's rewards are used, else "
                   "env copies")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of model and env copies")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--max-cycles", type=int, default=None, help="episode length override")
    p.add_argument("--reward-localization-weight", type=float, default=None)
    p.add_argument("--reward-heading-weight", type=float, default=None)
    p.add_argument("--reward-coverage-weight", type=float, default=None)
    p.add_argument("--collision-penalty", type=float, default=None)
    p.add_argument("--tip-over-penalty", type=float, default=None)
    p.add_argument("--learning-rate", type=float, default=d.learning_rate)
    p.add_argument("--n-steps", type=int, default=d.n_steps, help="PPO rollout length per slot")
    p.add_argument("--batch-size", type=int, default=d.batch_size)
    p.add_argument("--n-epochs", type=int, default=d.n_epochs)
    p.add_argument("--gamma", type=float, default=d.gamma)
    p.add_argument("--ent-coef", type=float, default=d.ent_coef)
    p.add_argument("--net-arch", type=int, nargs="+", default=list(d.net_arch))
    p.add_argument("--eval-freq", type=int, default=d.eval_freq,
                   help="agent steps between evaluations against the baseline (0 = off)")
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes)
    p.add_argument("--eval-baseline", default=d.eval_baseline, help=" | ".join(policy_names()))
    p.add_argument("--checkpoint-freq", type=int, default=d.checkpoint_freq,
                   help="agent steps between checkpoints (0 = off)")
    p.add_argument("--resume", default=None, help="checkpoint .zip or run DIR to continue from")
    p.add_argument("--max-wall-minutes", type=float, default=None,
                   help="stop training after this many minutes of wall time")
    p.add_argument("--no-reward-norm", action="store_true", help="no VecNormalize on rewards")
    p.add_argument("--clip-range", type=float, default=d.clip_range, help="PPO clip range")
    p.add_argument("--reward", dest="reward_mode", default=d.reward_mode, choices=REWARD_MODES,
                   help="env: the env's rewards; localize: minus the time to localize "
                        "(spread < 1.5 m, policies.learning.vec_env.TimeToLocalizeReward)")
    p.add_argument("--localize-step-reward", type=float, default=d.localize_step_reward,
                   help="--reward localize: penalty per step not yet localized")
    p.add_argument("--localize-team-weight", type=float, default=d.localize_team_weight,
                   help="--reward localize: weight in [0, 1] of the team's not-localized "
                        "fraction")
    p.add_argument("--localize-collision-weight", type=float,
                   default=d.localize_collision_weight,
                   help="--reward localize: penalty per new contact")
    p.add_argument("--obs-format", default=None, choices=("flat", "dict"),
                   help="observation format (default: the scenario's; dict: the belief map "
                        "read by a CNN, saved with the model)")
    p.add_argument("--bc-from", default=None, metavar="TEACHER",
                   help="behaviour-clone this teacher before PPO: wander, wander:SPEED, fsm, "
                        "gather, ... ('none': no cloning, e.g. over a scenario's default)")
    p.add_argument("--bc-episodes", type=int, default=d.bc_episodes,
                   help="teacher episodes to clone (seeds from policies.learning.training.BC_SEED)")
    p.add_argument("--bc-epochs", type=int, default=d.bc_epochs)
    p.add_argument("--bc-log-std", type=float, default=d.bc_log_std,
                   help="log standard deviation of the actions after cloning")
    p.add_argument("--dagger-rounds", type=int, default=d.dagger_rounds,
                   help="DAgger rounds after cloning: the clone drives, the teacher labels")
    p.add_argument("--dagger-epochs", type=int, default=d.dagger_epochs,
                   help="epochs of each DAgger refit (on all labels so far)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.add_argument("--backend", default="sb3", choices=("sb3", "rllib"),
                   help="sb3: stable-baselines3 on this machine; rllib: Ray RLlib's PPO "
                        "(policies.learning.rllib_backend, the rllib extra)")
    p.add_argument("--num-env-runners", type=int, default=None,
                   help="rllib: parallel sampling processes (default 1; 0 = in this process)")
    p.add_argument("--address", default=None,
                   help="rllib: address of a running Ray cluster (local Ray when unset)")
    return p


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """The :class:`TrainConfig` of parsed arguments."""
    args.scenario, overrides = scenario_and_overrides(args)
    no_bc = str(args.bc_from).lower() == "none"  # no cloning (nor DAgger) at all
    if args.max_cycles is not None:
        overrides["max_cycles"] = args.max_cycles
    for key in ("reward_localization_weight", "reward_heading_weight", "reward_coverage_weight",
                "collision_penalty", "tip_over_penalty"):
        value = getattr(args, key)
        if value is not None:
            overrides[key] = value
    return TrainConfig(
        out=args.out, scenario=args.scenario, estimator=args.estimator, algo=args.algo,
        timesteps=args.timesteps, n_envs=args.n_envs, n_procs=args.n_procs, seed=args.seed,
        vec_env=args.vec_env,
        overrides=overrides, learning_rate=args.learning_rate, n_steps=args.n_steps,
        batch_size=args.batch_size, n_epochs=args.n_epochs, gamma=args.gamma,
        ent_coef=args.ent_coef, net_arch=tuple(args.net_arch), eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes, eval_baseline=args.eval_baseline,
        checkpoint_freq=args.checkpoint_freq, resume=args.resume,
        progress_bar=not args.no_progress,
        max_wall_s=None if args.max_wall_minutes is None else 60.0 * args.max_wall_minutes,
        normalize_reward=not args.no_reward_norm, clip_range=args.clip_range,
        reward_mode=args.reward_mode, obs_format=args.obs_format,
        localize_step_reward=args.localize_step_reward,
        localize_team_weight=args.localize_team_weight,
        localize_collision_weight=args.localize_collision_weight,
        bc_from=None if no_bc else args.bc_from,
        bc_episodes=args.bc_episodes, bc_epochs=args.bc_epochs, bc_log_std=args.bc_log_std,
        dagger_rounds=0 if no_bc else args.dagger_rounds, dagger_epochs=args.dagger_epochs,
    )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Parse ``argv``; options left unset take the scenario's training defaults, if it has
    any (:func:`coop_loc_env.scenarios.training_defaults`; stable-baselines3 backend only),
    then the built-in ones."""
    from coop_loc_env.scenarios import training_defaults

    parser = build_parser()
    first, _ = parser.parse_known_args(argv)
    defaults = training_defaults(scenario_and_overrides(first)[0])
    if defaults and first.backend == "sb3":  # the scenarios' recipes are stable-baselines3 ones
        parser.set_defaults(**defaults)
    given = sys.argv[1:] if argv is None else argv
    if first.resume and not any(a.split("=")[0] == "--bc-from" for a in given):
        parser.set_defaults(bc_from="none")  # the resumed run was cloned when it started
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Train; returns the exit status (2 on bad input)."""
    try:
        args = parse_args(argv)
        if args.backend == "sb3":
            require("stable_baselines3", "torch", extra="train")
        else:
            require("ray", "torch", extra="rllib")
        cfg = config_from_args(args)
        cfg.validate()
        import coop_loc_env

        coop_loc_env.make_config(cfg.scenario, **cfg.env_overrides())
        if args.backend == "rllib":
            return _train_rllib(cfg, args)
        if args.num_env_runners is not None or args.address is not None:
            raise ValueError("--num-env-runners and --address need --backend rllib")
        steps = trained_timesteps(cfg)
        if steps != cfg.timesteps:
            print(f"note: training {steps} agent steps, not {cfg.timesteps}: the agent slots "
                  f"(--n-envs x robots) step together, and PPO learns in whole rollouts of "
                  f"--n-steps steps per slot")
        if cfg.bc_from is not None:
            rounds = f" and {cfg.dagger_rounds} DAgger rounds" if cfg.dagger_rounds else ""
            print(f"behaviour cloning {cfg.bc_from} before PPO: {cfg.bc_episodes} episodes"
                  f"{rounds}, about {estimate_cloning_s(cfg):.0f} s to collect here, plus "
                  f"the fits (--bc-from none skips it)", flush=True)
        summary = train(cfg)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if summary["bc"]:
        bc = summary["bc"]
        print(f"behaviour cloning of {bc['teacher']}: {bc['episodes']} episodes "
              f"({bc['samples']} samples) collected in {bc['collect_wall_s']:.0f} s, fitted in "
              f"{bc['wall_s']:.0f} s (action MSE {bc['action_mse']:.4f}, value MSE "
              f"{bc['value_mse']:.4f})")
    print(f"trained {summary['timesteps']} agent steps in {summary['wall_s']:.0f} s "
          f"({summary['steps_per_s']:.0f} steps/s, {summary['vec_env']} env), "
          f"{summary['total_wall_s']:.0f} s in all; "
          f"final model: {summary['final_model']}")
    for ev in summary["evals"]:
        print(f"  eval at {ev['timesteps']:.0f}: error {ev['localization_error_m']:.3f} m, "
              f"coverage {ev['coverage']:.4f}")
    if summary["baseline"]:
        b = summary["baseline"]
        print(f"  baseline {args.eval_baseline}: error {b['localization_error_m']:.3f} m, "
              f"coverage {b['coverage']:.4f}")
    return 0


def _train_rllib(cfg: TrainConfig, args: argparse.Namespace) -> int:
    """``--backend rllib`` (raises ``ValueError`` on options that path does not have)."""
    from policies.learning.rllib_backend import run_from_train_config, train_rllib

    summary = train_rllib(run_from_train_config(cfg, args.num_env_runners, args.address))
    print(f"trained {summary['timesteps']} agent steps with RLlib in {summary['wall_s']:.0f} s "
          f"({summary['steps_per_s']:.0f} steps/s, {summary['vec_env']} env), "
          f"{summary['total_wall_s']:.0f} s in all; "
          f"checkpoint: {summary['checkpoint']}")
    return 0


if __name__ == "__main__":
    if {"rllib", "--backend=rllib"} & set(sys.argv) and "PYTHONHASHSEED" not in os.environ:
        # RLlib orders agents by iterating sets of their names: with string hashing fixed,
        # the same seed gives the same samples and batches (the env runners get it too).
        os.environ["PYTHONHASHSEED"] = "0"
        os.execv(sys.executable, [sys.executable, *sys.argv])
    sys.exit(run_script(main))
