"""Train one policy shared by all robots with stable-baselines3 (the library of train.py).

:func:`train` builds a :class:`~policies.learning.sb3_vec_env.ParallelEnvVecEnv` (every agent
of ``n_envs`` env copies is one slot, copies stepped in ``n_procs`` processes),
wraps it in ``VecNormalize`` (rewards only: observations are already scaled
by the env, and an unnormalized-input model is what ``scripts/evaluate.py``
loads), and runs PPO (default) or SAC with:

* SB3's progress bar (a plain tqdm bar when ``rich``, which SB3's bar needs,
  is not installed) and TensorBoard logs (``DIR/tb``);
* :class:`BaselineEvalCallback`: every ``eval_freq`` env steps the current
  policy (deterministic) runs ``eval_episodes`` seeded episodes and the team
  localization error, coverage, collisions and tip-overs are logged under
  ``eval/``, next to the same figures of the FSM baseline on the same seeds
  (``baseline/``, computed once) and their ratio ``eval/error_ratio_vs_baseline``;
* checkpoints every ``checkpoint_freq`` env steps (``DIR/checkpoints``), and
  ``resume`` from a checkpoint ``.zip`` or a run directory (its newest
  checkpoint, with its reward-normalization statistics): the model goes on
  for ``timesteps`` more steps, its step counter continuing;
* an optional wall-clock limit ``max_wall_s`` (training stops there, the
  model is saved as usual);
* the final model at ``DIR/final_model.zip``, the policy with the lowest
  evaluated error so far at ``DIR/best_model.zip`` (when evaluating), and the
  run's settings at ``DIR/train_config.json``;
* ``reward_mode="localize"``: the env's rewards replaced by minus the time to
  localize (:class:`policies.learning.vec_env.TimeToLocalizeReward`, weights
  ``localize_step_reward``, ``localize_team_weight``, ``localize_collision_weight``);
* ``bc_from``: before PPO, behaviour cloning of a scripted teacher
  (:mod:`policies.learning.imitation`; ``bc_episodes`` seeded episodes from
  ``BC_SEED``, ``bc_epochs``, exploration ``bc_log_std``); the critic is fitted
  to the teacher's returns too when rewards are not normalized. The clone is
  saved as ``DIR/bc_model.zip``; the wall-clock limit counts the cloning;
  ``dagger_rounds`` DAgger rounds refine the clone (``dagger_epochs`` each);
* ``obs_format="dict"`` (the env's observation a ``Dict`` with the belief map):
  SB3's ``MultiInputPolicy`` with :class:`~policies.learning.belief_cnn.BeliefMapExtractor`
  (a small CNN on the map, the vector passed through); the model keeps the
  observation settings it was trained with (``model.env_settings``, saved in the
  ``.zip``), which evaluation applies (:func:`policies.episode.env_overrides_for`).

"env steps" here are SB3 timesteps: one per agent slot per step, so one
parallel-env step of a 3-robot team counts 3.
"""

from __future__ import annotations

import dataclasses
import json
import re
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from coop_loc_env.threads import set_torch_threads
from policies.episode import run_episode
from policies.learning.imitation import (
    behaviour_clone,
    collect_demonstrations,
    concat_observations,
    make_teacher,
)
from policies.learning.learned import LearnedPolicy
from policies.learning.loader import make_policy
from policies.learning.vec_env import REWARD_MODES, TimeToLocalizeReward, make_env_fn

ALGOS = ("PPO", "SAC")
#: How the training samples: ``auto`` (see :func:`vec_env_kind`), one batched env, or copies.
VEC_ENVS = ("auto", "batched", "copies")
OBS_DICT_FIELDS = ("belief_map_cells", "belief_map_headings", "belief_modes")
EVAL_SEED = 100_000  # evaluation episodes use seeds EVAL_SEED + k, apart from training seeds
BC_SEED = 200_000  # behaviour-cloning demonstrations use seeds BC_SEED + k


@dataclass
class TrainConfig:
    """Settings of a training run (every field is a ``scripts/train.py`` option).

    ``overrides`` are env config overrides (reward weights, ``max_cycles``, ...);
    ``estimator`` is passed to the env too. ``n_steps``/``batch_size`` are PPO's
    rollout length per slot and minibatch size (SAC uses ``batch_size`` and
    ``buffer_size``).
    """

    out: str
    scenario: str = "outdoor_terrain"
    estimator: str | None = None
    algo: str = "PPO"
    timesteps: int = 100_000
    n_envs: int = 2
    n_procs: int = 1
    vec_env: str = "auto"
    seed: int = 0
    overrides: dict[str, Any] = field(default_factory=dict)
    learning_rate: float = 3e-4
    n_steps: int = 256
    batch_size: int = 256
    n_epochs: int = 5
    gamma: float = 0.99
    ent_coef: float = 0.0
    net_arch: tuple[int, ...] = (64, 64)
    buffer_size: int = 200_000
    eval_freq: int = 50_000
    eval_episodes: int = 2
    eval_baseline: str = "fsm"
    checkpoint_freq: int = 50_000
    resume: str | None = None
    max_wall_s: float | None = None
    progress_bar: bool = True
    normalize_reward: bool = True
    verbose: int = 0
    clip_range: float = 0.2
    reward_mode: str = "env"
    obs_format: str | None = None
    localize_step_reward: float = 0.1
    localize_team_weight: float = 0.0
    localize_collision_weight: float = 0.0
    bc_from: str | None = None
    bc_episodes: int = 10
    bc_epochs: int = 30
    bc_log_std: float = -1.0
    dagger_rounds: int = 0
    dagger_epochs: int = 15

    def validate(self) -> None:
        """Raise ``ValueError`` naming a bad field."""
        if self.algo.upper() not in ALGOS:
            raise ValueError(f"algo must be one of {ALGOS}, got {self.algo!r}")
        for key in ("timesteps", "n_envs", "n_procs", "n_steps", "batch_size", "n_epochs",
                    "buffer_size", "eval_episodes"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be a positive integer, got {value!r}")
        for key in ("eval_freq", "checkpoint_freq"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{key} must be an integer >= 0 (0 = off), got {value!r}")
        if self.n_procs > self.n_envs:
            raise ValueError(f"n_procs must be <= n_envs ({self.n_envs}), got {self.n_procs!r}")
        if self.vec_env not in VEC_ENVS:
            raise ValueError(f"vec_env must be one of {VEC_ENVS}, got {self.vec_env!r}")
        if self.vec_env == "batched" and (self.n_procs > 1 or self.reward_mode != "env"):
            raise ValueError("vec_env 'batched' steps every world in this process with the "
                             "env's rewards: it needs n_procs 1 and reward_mode 'env'")
        if self.max_wall_s is not None and not self.max_wall_s > 0:
            raise ValueError(f"max_wall_s must be > 0, got {self.max_wall_s!r}")
        if not (0 < self.gamma <= 1):
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma!r}")
        if not self.learning_rate > 0:
            raise ValueError(f"learning_rate must be > 0, got {self.learning_rate!r}")
        if not self.net_arch or any(int(h) < 1 for h in self.net_arch):
            raise ValueError(f"net_arch must be positive layer sizes, got {self.net_arch!r}")
        if not 0 < self.clip_range <= 1:
            raise ValueError(f"clip_range must be in (0, 1], got {self.clip_range!r}")
        if self.reward_mode not in REWARD_MODES:
            raise ValueError(f"reward_mode must be one of {REWARD_MODES}, "
                             f"got {self.reward_mode!r}")
        TimeToLocalizeReward.check_kwargs(**self.reward_kwargs())
        if isinstance(self.dagger_rounds, bool) or not isinstance(self.dagger_rounds, int) or (
                self.dagger_rounds < 0):
            raise ValueError(f"dagger_rounds must be an integer >= 0, got {self.dagger_rounds!r}")
        if self.resume:
            check_checkpoint(self.resume)
        if self.dagger_rounds and self.bc_from is None:
            raise ValueError("dagger_rounds needs bc_from (the teacher that labels the states)")
        if self.bc_from is not None:
            if self.algo.upper() != "PPO":
                raise ValueError(f"bc_from needs algo PPO, got {self.algo!r}")
            if self.resume:
                raise ValueError("bc_from and resume exclude each other (a resumed run was "
                                 "cloned when it started): drop --bc-from, or use "
                                 "--bc-from none")
            make_teacher(self.bc_from)  # fail early on a bad spec
            for key in ("bc_episodes", "bc_epochs", "dagger_epochs"):
                value = getattr(self, key)
                if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                    raise ValueError(f"{key} must be a positive integer, got {value!r}")

    def reward_kwargs(self) -> dict[str, float]:
        """Keyword arguments of :class:`~policies.learning.vec_env.TimeToLocalizeReward`."""
        return {"step_reward": self.localize_step_reward,
                "team_weight": self.localize_team_weight,
                "collision_weight": self.localize_collision_weight}

    def env_fn(self):
        """The factory of one training env (reward-wrapped when ``reward_mode="localize"``)."""
        kwargs = self.reward_kwargs() if self.reward_mode == "localize" else None
        return make_env_fn(self.scenario, reward_mode=self.reward_mode, reward_kwargs=kwargs,
                           **self.env_overrides())

    def env_overrides(self) -> dict[str, Any]:
        """The env config overrides of this run (``estimator`` included when set)."""
        out = dict(self.overrides)
        if self.obs_format is not None:
            out.setdefault("obs_format", self.obs_format)
        if self.estimator is not None:
            out["estimator"] = self.estimator
        return out


def trained_timesteps(cfg: TrainConfig) -> int:
    """How many agent steps ``cfg`` trains: SB3 steps all ``n_envs * n_robots`` agent slots
    at once, and PPO learns in whole rollouts of ``n_steps`` steps of every slot, so
    ``timesteps`` rounds up to a multiple of that."""
    import coop_loc_env

    slots = cfg.n_envs * coop_loc_env.make_config(cfg.scenario, **cfg.env_overrides()).n_robots
    chunk = slots * (cfg.n_steps if cfg.algo.upper() == "PPO" else 1)
    return -(-cfg.timesteps // chunk) * chunk


def vec_env_kind(cfg: TrainConfig) -> str:
    """``"batched"`` (one batched env in this process) or ``"copies"`` (env copies, in
    ``n_procs`` processes). ``auto`` picks the batched env whenever it can run the
    config (one process, the env's rewards): it samples exactly what the copies sample
    without their per-agent dicts (docs/scaling.md); several processes and the
    ``localize`` reward (a wrapper of each copy) take the copies."""
    if cfg.vec_env != "auto":
        return cfg.vec_env
    return "batched" if cfg.n_procs == 1 and cfg.reward_mode == "env" else "copies"


def make_vec_env(cfg: TrainConfig):
    """The training ``VecEnv``: slots per agent, reward-normalized when asked."""
    from stable_baselines3.common.vec_env import VecNormalize

    if vec_env_kind(cfg) == "batched":
        from policies.learning.sb3_batched import BatchedVecEnv

        venv = BatchedVecEnv(cfg.scenario, n_envs=cfg.n_envs, **cfg.env_overrides())
    else:
        from policies.learning.sb3_vec_env import ParallelEnvVecEnv

        venv = ParallelEnvVecEnv(cfg.env_fn(), n_envs=cfg.n_envs, n_procs=cfg.n_procs)
    if cfg.normalize_reward:
        venv = VecNormalize(venv, norm_obs=False, norm_reward=True, gamma=cfg.gamma)
    return venv


def make_model(cfg: TrainConfig, venv, tensorboard_log: str | None):
    """A fresh PPO/SAC model on ``venv``."""
    import stable_baselines3 as sb3

    algo = cfg.algo.upper()
    arch = [int(h) for h in cfg.net_arch]
    common = dict(
        learning_rate=cfg.learning_rate, gamma=cfg.gamma, seed=cfg.seed, verbose=cfg.verbose,
        tensorboard_log=tensorboard_log, device="cpu",
    )
    policy, extractor = "MlpPolicy", {}
    if isinstance(venv.observation_space, spaces.Dict):  # obs_format="dict": CNN on the map
        from policies.learning.belief_cnn import BeliefMapExtractor

        policy, extractor = "MultiInputPolicy", {"features_extractor_class": BeliefMapExtractor}
    if algo == "PPO":
        model = sb3.PPO(
            policy, venv, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
            n_epochs=cfg.n_epochs, ent_coef=cfg.ent_coef, clip_range=cfg.clip_range,
            policy_kwargs=dict(net_arch=dict(pi=arch, vf=arch), **extractor), **common,
        )
    else:
        model = sb3.SAC(
            policy, venv, batch_size=cfg.batch_size, buffer_size=cfg.buffer_size,
            learning_starts=min(1000, cfg.timesteps),
            policy_kwargs=dict(net_arch=arch, **extractor), **common,
        )
    model.env_settings = observation_settings(cfg.scenario, cfg.env_overrides())
    return model


def observation_settings(scenario: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The config fields that shape a policy's observations (saved with the model, so an
    evaluation builds the env its network reads): the observation format and, for the
    dict observation, the belief map's grid, headings and modes."""
    import coop_loc_env

    cfg = coop_loc_env.make_config(scenario, **overrides)
    keys = ("obs_format",) + (OBS_DICT_FIELDS if cfg.obs_format == "dict" else ())
    return {k: getattr(cfg, k) for k in keys}


def evaluate_figures(
    scenario: str, policy, n_episodes: int, overrides: dict[str, Any], seed: int = EVAL_SEED
) -> dict[str, float]:
    """Mean figures of ``policy`` over ``n_episodes`` seeded episodes (no progress bar)."""
    import coop_loc_env

    env = coop_loc_env.parallel_env(scenario, **overrides)
    try:
        eps = [run_episode(env, policy, seed + k) for k in range(n_episodes)]
    finally:
        env.close()
    keys = ("localization_error_m", "coverage", "collisions", "tip_overs", "team_return")
    return {k: float(np.mean([ep[k] for ep in eps])) for k in keys}


def _callbacks(cfg: TrainConfig, out: Path, deadline: float | None = None):
    from stable_baselines3.common.callbacks import BaseCallback, CheckpointCallback

    class BaselineEvalCallback(BaseCallback):
        """Every ``eval_freq`` env steps, log the policy's figures next to the baseline's."""

        def __init__(self) -> None:
            super().__init__()
            self.next_eval = 0
            self.baseline: dict[str, float] | None = None
            self.history: list[dict[str, float]] = []
            self.best = float("inf")

        def _on_training_start(self) -> None:
            self.next_eval = self.num_timesteps + cfg.eval_freq
            if cfg.eval_baseline:
                self.baseline = evaluate_figures(
                    cfg.scenario, make_policy(cfg.eval_baseline), cfg.eval_episodes,
                    cfg.env_overrides(),
                )
            if cfg.bc_from is not None:  # the clone itself is the first candidate
                self.evaluate()

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += cfg.eval_freq
                self.evaluate()
            return True

        def evaluate(self) -> dict[str, float]:
            policy = LearnedPolicy(self.model, name="learned")
            figs = evaluate_figures(cfg.scenario, policy, cfg.eval_episodes, cfg.env_overrides())
            for key, value in figs.items():
                self.logger.record(f"eval/{key}", value)
            if self.baseline is not None:
                for key, value in self.baseline.items():
                    self.logger.record(f"baseline/{key}", value)
                base_err = self.baseline["localization_error_m"]
                ratio = figs["localization_error_m"] / base_err if base_err > 0 else float("nan")
                self.logger.record("eval/error_ratio_vs_baseline", ratio)
            self.logger.dump(self.num_timesteps)
            self.history.append({"timesteps": float(self.num_timesteps), **figs})
            if figs["localization_error_m"] < self.best:  # keep the best evaluated policy
                self.best = figs["localization_error_m"]
                self.model.save(str(out / "best_model.zip"))
            return figs

    callbacks = []
    if cfg.checkpoint_freq:
        slots = _n_slots(cfg)
        callbacks.append(CheckpointCallback(
            save_freq=max(1, cfg.checkpoint_freq // slots), save_path=str(out / "checkpoints"),
            name_prefix="model", save_vecnormalize=True,
        ))
    class WallClockLimit(BaseCallback):
        """Stop training at ``deadline`` (``max_wall_s`` after ``train`` began)."""

        def _on_training_start(self) -> None:
            self.deadline = (deadline if deadline is not None
                             else time.perf_counter() + cfg.max_wall_s)

        def _on_step(self) -> bool:
            return time.perf_counter() < self.deadline

    if cfg.max_wall_s is not None:
        callbacks.append(WallClockLimit())
    evaluator = BaselineEvalCallback() if cfg.eval_freq else None
    if evaluator is not None:
        callbacks.append(evaluator)
    return callbacks, evaluator


def _has_rich() -> bool:
    """Whether SB3's own progress bar can run (it needs ``tqdm`` and ``rich``)."""
    import importlib.util

    return importlib.util.find_spec("rich") is not None and (
        importlib.util.find_spec("tqdm") is not None
    )


def _tqdm_progress(total: int):
    """A plain-tqdm progress bar callback (SB3's needs ``rich``, which may be missing)."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class TqdmProgress(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(total=total, unit="step", desc="training")
            self.last = self.num_timesteps

        def _on_step(self) -> bool:
            self.bar.update(self.num_timesteps - self.last)
            self.last = self.num_timesteps
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return TqdmProgress()


def _n_slots(cfg: TrainConfig) -> int:
    import coop_loc_env

    return cfg.n_envs * coop_loc_env.make_config(cfg.scenario, **cfg.env_overrides()).n_robots


def find_checkpoint(path: str | Path) -> Path:
    """A checkpoint ``.zip`` itself, or the newest one of a run directory."""
    path = Path(path)
    if path.is_file():
        return path
    if path.is_dir():
        zips = list((path / "checkpoints").glob("model_*_steps.zip")) + list(
            path.glob("model_*_steps.zip")
        )
        if zips:
            return max(zips, key=lambda p: int(re.findall(r"_(\d+)_steps", p.name)[-1]))
        if (path / "final_model.zip").is_file():
            return path / "final_model.zip"
    raise ValueError(f"resume: no checkpoint found at {str(path)!r}")


def check_checkpoint(path: str | Path) -> Path:
    """The checkpoint :func:`find_checkpoint` picks, checked to be a zip archive (what
    stable-baselines3 saves); raises ``ValueError`` saying what is wrong."""
    if not Path(path).exists():
        raise ValueError(f"resume: {str(path)!r} does not exist (give a checkpoint .zip or "
                         f"a training run's DIR)")
    ckpt = find_checkpoint(path)
    if not zipfile.is_zipfile(ckpt):
        raise ValueError(f"resume: {str(ckpt)!r} is not a stable-baselines3 checkpoint (not a "
                         f"zip archive)")
    return ckpt


def estimate_cloning_s(cfg: TrainConfig) -> float:
    """Seconds :func:`warm_start` will spend collecting demonstrations, from the time one
    teacher episode takes here (fitting the clone comes on top)."""
    probe = collect_demonstrations(cfg.env_fn(), make_teacher(cfg.bc_from), 1, BC_SEED,
                                   gamma=cfg.gamma)
    return probe["wall_s"] * cfg.bc_episodes * (1 + cfg.dagger_rounds)


def _vecnormalize_of(ckpt: Path) -> Path | None:
    """The reward-normalization statistics saved with a checkpoint, if any."""
    steps = re.findall(r"_(\d+)_steps", ckpt.name)
    candidates = [ckpt.parent / f"model_vecnormalize_{steps[-1]}_steps.pkl"] if steps else []
    candidates.append(ckpt.parent / "vecnormalize.pkl")
    return next((c for c in candidates if c.is_file()), None)


def warm_start(cfg: TrainConfig, model) -> dict[str, Any]:
    """Behaviour-clone ``cfg.bc_from`` into ``model`` (PPO) on the training env; returns
    the demonstration and fit figures (the critic is fitted only without reward
    normalization, whose scale it could not know)."""
    demos = collect_demonstrations(cfg.env_fn(), make_teacher(cfg.bc_from), cfg.bc_episodes,
                                   BC_SEED, gamma=cfg.gamma)
    fit = behaviour_clone(model, demos, epochs=cfg.bc_epochs, log_std=cfg.bc_log_std,
                          value=not cfg.normalize_reward, seed=cfg.seed)
    collect_s, team_steps = demos["wall_s"], demos["steps"]
    rounds = []
    for r in range(1, cfg.dagger_rounds + 1):  # the clone drives, the teacher labels

        def actor(batch):
            return model.predict(batch, deterministic=True)[0]

        more = collect_demonstrations(cfg.env_fn(), make_teacher(cfg.bc_from), cfg.bc_episodes,
                                      BC_SEED + r * cfg.bc_episodes, gamma=cfg.gamma,
                                      actor=actor)
        collect_s += more["wall_s"]
        team_steps += more["steps"]
        demos["obs"] = concat_observations([demos["obs"], more["obs"]])
        for key in ("actions", "returns"):
            demos[key] = np.concatenate([demos[key], more[key]])
        fit = behaviour_clone(model, demos, epochs=cfg.dagger_epochs, log_std=cfg.bc_log_std,
                              value=not cfg.normalize_reward, seed=cfg.seed + r)
        rounds.append({"round": r, "samples": len(demos["actions"]),
                       "action_mse": fit["action_mse"]})
    return {"teacher": cfg.bc_from, "episodes": demos["episodes"], "team_steps": team_steps,
            "collect_wall_s": collect_s, "mean_return": float(demos["returns"].mean()),
            "dagger": rounds, **fit}


def train(cfg: TrainConfig) -> dict[str, Any]:
    """Run the training described by ``cfg``; returns a summary (paths, timings, evals).

    The summary holds ``final_model`` (path), ``timesteps`` (total, counting a
    resumed run's earlier steps), ``wall_s`` (the RL phase), ``total_wall_s``
    (from the call, cloning included), ``steps_per_s``, ``bc`` (the
    behaviour-cloning figures, or ``None``) and ``evals`` (the periodic
    evaluation records).
    """
    import stable_baselines3 as sb3

    cfg.validate()
    set_torch_threads()  # small networks: more threads wait (coop_loc_env.threads)
    t0 = time.perf_counter()
    deadline = None if cfg.max_wall_s is None else t0 + cfg.max_wall_s
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    config = dataclasses.asdict(cfg)
    (out / "train_config.json").write_text(json.dumps(config, indent=2, default=str) + "\n")
    venv = make_vec_env(cfg)
    tb = str(out / "tb")
    try:
        if cfg.resume:
            ckpt = find_checkpoint(cfg.resume)
            stats = _vecnormalize_of(ckpt)
            if cfg.normalize_reward and stats is not None:
                from stable_baselines3.common.vec_env import VecNormalize

                venv = VecNormalize.load(str(stats), venv.venv)
            algo = getattr(sb3, cfg.algo.upper())
            try:
                model = algo.load(str(ckpt), env=venv, device="cpu", tensorboard_log=tb)
            except (ValueError, KeyError, AssertionError, zipfile.BadZipFile, RuntimeError) as err:
                reason = str(err).removeprefix("Error: ").splitlines()[0]
                raise ValueError(f"resume: cannot load {str(ckpt)!r} as a {cfg.algo.upper()} "
                                 f"model: {reason}") from None
            reset = False
        else:
            model = make_model(cfg, venv, tb)
            reset = True
        bc = None
        if cfg.bc_from is not None:
            bc = warm_start(cfg, model)
            model.save(str(out / "bc_model.zip"))
        callbacks, evaluator = _callbacks(cfg, out, deadline)
        sb3_bar = cfg.progress_bar and _has_rich()
        if cfg.progress_bar and not sb3_bar:
            callbacks.append(_tqdm_progress(cfg.timesteps))
        start_steps = model.num_timesteps
        start = time.perf_counter()
        model.learn(
            total_timesteps=cfg.timesteps, callback=callbacks, progress_bar=sb3_bar,
            reset_num_timesteps=reset, tb_log_name=cfg.algo.upper(),
        )
        wall = time.perf_counter() - start
        final = out / "final_model.zip"
        model.save(str(final))
        if cfg.normalize_reward:
            venv.save(str(out / "vecnormalize.pkl"))
    finally:
        venv.close()
    done = model.num_timesteps - start_steps
    summary = {
        "final_model": str(final),
        "timesteps": int(model.num_timesteps),
        "wall_s": wall,
        "total_wall_s": time.perf_counter() - t0,
        "bc": bc,
        "steps_per_s": done / wall if wall > 0 else float("nan"),
        "vec_env": vec_env_kind(cfg),
        "evals": evaluator.history if evaluator is not None else [],
        "best_model": str(out / "best_model.zip") if evaluator is not None and evaluator.history
        else None,
        "baseline": evaluator.baseline if evaluator is not None else None,
    }
    (out / "train_summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")
    return summary
