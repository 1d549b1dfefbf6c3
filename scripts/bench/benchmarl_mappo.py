"""BenchMARL on a coop_loc task for a wall-clock budget, then evaluated beside other policies.

Trains ``--algo`` (BenchMARL's YAML defaults, CPU, no loggers) on ``coop_loc/<scenario>``
until ``--minutes`` of wall time have passed (checked after each training iteration),
prints the frames/s of collection and of the whole run, then runs ``--episodes``
evaluation episodes (seeds ``--seed-eval`` on) of the trained policy (deterministic
actions) and of every ``--compare`` policy (a name or a training directory, as for
``scripts/evaluate.py``), with a 95 % interval of the team localization error::

    python scripts/bench/benchmarl_mappo.py --scenario rendezvous --minutes 6 --episodes 20 \\
        --compare runs/ppo_rdv,gather --json runs/mappo_rdv.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from coop_loc_env.cli import ScriptParser, require, run_script


class _Stop(Exception):
    """Raised by the wall-clock callback to end training."""


class _TrainedPolicy:
    """A BenchMARL policy acting in the parallel env (for :func:`policies.episode.run_episode`)."""

    name = "benchmarl"

    def __init__(self, policy) -> None:
        self.policy = policy
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        self.env = env

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        import torch
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        env = self.env
        n = len(env.possible_agents)
        stacked = np.zeros((n, *next(iter(obs.values())).shape), dtype=np.float32)
        for agent, o in obs.items():
            stacked[env.agent_name_mapping[agent]] = o
        td = TensorDict({"robot": TensorDict({"observation": torch.from_numpy(stacked)},
                                             batch_size=(n,))}, batch_size=())
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            act = self.policy(td).get(("robot", "action")).numpy()
        return {a: act[env.agent_name_mapping[a]] for a in env.agents}


def _WallClock(base: type, deadline: float, stats: dict):
    """A BenchMARL callback that ends training after ``deadline`` (``perf_counter``); it
    pickles (BenchMARL saves its callbacks) as a plain instance of a module-level class."""
    global _WallClockCallback

    class _WallClockCallback(base):
        def __init__(self) -> None:
            super().__init__()
            self.deadline, self.stats = deadline, stats

        def on_batch_collected(self, batch) -> None:
            self.stats["iterations"] += 1

        def on_train_end(self, training_td, group: str) -> None:
            if time.perf_counter() >= self.deadline:
                raise _Stop

    _WallClockCallback.__qualname__ = "_WallClockCallback"
    return _WallClockCallback()


def _train(args: argparse.Namespace) -> tuple[object, dict]:
    import torch
    from benchmarl.algorithms import IppoConfig, MappoConfig
    from benchmarl.experiment import Callback, Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig

    from coop_loc_env.benchmarl import CoopLocTask

    torch.set_num_threads(1)
    algos = {"mappo": MappoConfig, "ippo": IppoConfig}
    task = CoopLocTask[args.scenario.upper()].get_from_yaml()
    cfg = ExperimentConfig.get_from_yaml()
    cfg.sampling_device = cfg.train_device = "cpu"
    cfg.max_n_frames = 10**9  # the wall clock ends the run
    cfg.evaluation = False
    cfg.loggers = []
    cfg.checkpoint_interval = 0
    cfg.create_json = False
    cfg.render = False
    cfg.save_folder = args.save_folder
    stats = {"iterations": 0}
    t0 = time.perf_counter()
    clock = _WallClock(Callback, t0 + 60.0 * args.minutes, stats)
    exp = Experiment(task=task, algorithm_config=algos[args.algo].get_from_yaml(),
                     model_config=MlpConfig.get_from_yaml(), seed=args.seed, config=cfg,
                     callbacks=[clock])
    try:
        exp.run()
    except _Stop:
        pass
    wall = time.perf_counter() - t0
    stats.update(frames=int(exp.total_frames), wall_s=wall,
                 frames_per_s=exp.total_frames / wall,
                 frames_per_batch=cfg.collected_frames_per_batch(True))
    return exp.policy, stats


def main(argv: list[str] | None = None) -> int:
    p = ScriptParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="rendezvous")
    p.add_argument("--algo", default="mappo", choices=("mappo", "ippo"))
    p.add_argument("--minutes", type=float, default=6.0)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--seed-eval", type=int, default=1000)
    p.add_argument("--compare", default="", help="comma-separated policies to evaluate too")
    p.add_argument("--save-folder", default=None)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if args.minutes <= 0 or args.episodes < 2:
        print(f"error: need --minutes > 0 and --episodes >= 2, got {args.minutes}, "
              f"{args.episodes}", file=sys.stderr)
        return 2
    require("torch", "torchrl", "benchmarl", "hydra", extra="benchmarl")
    import coop_loc_env
    from policies.episode import run_episode
    from policies.experiments.compare import mean_ci
    from policies.learning.loader import make_policy

    policy, stats = _train(args)
    print(f"{args.algo} on {args.scenario}: {stats['frames']} frames in {stats['wall_s']:.0f} s "
          f"({stats['frames_per_s']:.0f} frames/s end to end, {stats['iterations']} iterations "
          f"of {stats['frames_per_batch']} frames)", flush=True)
    env = coop_loc_env.parallel_env(args.scenario)
    rows = {args.algo: _TrainedPolicy(policy)}
    for spec in filter(None, args.compare.split(",")):
        rows[spec] = make_policy(spec)
    results = {"train": stats, "eval": {}}
    for name, pol in rows.items():
        errs = [run_episode(env, pol, seed=args.seed_eval + k)["localization_error_m"]
                for k in range(args.episodes)]
        mean, lo, hi = mean_ci(np.array(errs))
        results["eval"][name] = {"errors_m": errs, "mean": mean, "ci95": [lo, hi]}
        print(f"{name:30s} team localization error {mean:.3f} m (95% CI {lo:.3f}-{hi:.3f}) "
              f"over {args.episodes} episodes", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
