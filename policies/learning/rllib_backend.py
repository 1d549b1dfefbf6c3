"""Ray RLlib as a training backend: PPO (new API stack), one policy shared by all robots.

* :class:`CoopLocMultiAgentEnv` runs the env as an RLlib ``MultiAgentEnv``. It
  keeps a time-limit cut distinct from a termination: RLlib's
  ``MultiAgentEpisode`` declares an episode *terminated* (and so every agent
  in it, which drops the value bootstrap) as soon as every agent has a done
  flag, truncated ones included. When the episode ends at ``max_cycles`` the
  wrapper therefore reports the cut as ``truncateds["__all__"]`` alone: each
  agent still driving then ends truncated (its value bootstrapped), and a
  robot that tipped over, at any step, ends terminated (no bootstrap).
* :func:`train_rllib` trains RLlib's PPO on local Ray or a running Ray cluster
  (``address``) with ``num_env_runners`` parallel sampling processes; it
  writes the algorithm checkpoint ``DIR/checkpoint`` (also every
  ``checkpoint_freq`` agent steps while training), TensorBoard scalars
  (``DIR/tb``), ``DIR/train_config.json`` and ``DIR/train_summary.json``.
* :class:`RLlibPolicy` loads the trained network from such a ``DIR`` for
  :func:`policies.learning.loader.load_learned_policy` (``scripts/evaluate.py --policy DIR``).

Ray is imported only by this module (``pip install -e ".[rllib]"``).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from ray.rllib.env.multi_agent_env import MultiAgentEnv

import coop_loc_env
from coop_loc_env.threads import set_torch_threads
from policies.learning.inference import INFERENCE_THREADS, check_observation_shape, is_rllib_run

ENV_NAME = "coop_loc_rllib"
MODULE_ID = "shared"  # the one policy every robot maps to
CHECKPOINT = "checkpoint"  # DIR/checkpoint: the final algorithm checkpoint
MODULE_PATH = ("learner_group", "learner", "rl_module", MODULE_ID)
HISTORY_KEYS = {  # train_summary.json's history: name -> RLlib result key
    "episode_return_mean": "env_runners/episode_return_mean",
    "policy_loss": f"learners/{MODULE_ID}/policy_loss",
    "vf_loss": f"learners/{MODULE_ID}/vf_loss",
}


class CoopLocMultiAgentEnv(MultiAgentEnv):
    """The env as an RLlib ``MultiAgentEnv`` (time-limit cuts stay truncations).

    Args:
        config: ``{"scenario": NAME, **config overrides}`` (RLlib's ``env_config``).
    """

    def __init__(self, config: dict[str, Any] | None = None) -> None:
        super().__init__()
        config = dict(config or {})
        scenario = config.pop("scenario", "outdoor_terrain")
        self.env = coop_loc_env.parallel_env(scenario, **config)
        self.possible_agents = list(self.env.possible_agents)
        self.agents: list[str] = []
        self.observation_spaces = {a: self.env.observation_space(a) for a in self.possible_agents}
        self.action_spaces = {a: self.env.action_space(a) for a in self.possible_agents}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode (RLlib seeds it)."""
        obs, infos = self.env.reset(seed=seed, options=options)
        self.agents = list(self.env.agents)
        return obs, infos

    def step(self, action_dict: dict[str, np.ndarray]):
        """One env step; a time-limit cut is reported as ``truncateds["__all__"]`` only."""
        obs, rewards, term, trunc, infos = self.env.step(action_dict)
        self.agents = list(self.env.agents)
        terminateds: dict[str, bool] = dict(term)
        cut = any(trunc.values())
        if cut:  # no per-agent truncation flags: with them RLlib would mark all terminated
            truncateds: dict[str, bool] = {"__all__": True}
            terminateds["__all__"] = False
        else:
            truncateds = dict.fromkeys(trunc, False)
            truncateds["__all__"] = False
            terminateds["__all__"] = not self.agents
        return obs, rewards, terminateds, truncateds, infos

    def render(self) -> np.ndarray | None:
        """The env's frame (``render_mode`` as set in the env config)."""
        return self.env.render()

    def close(self) -> None:
        """Close the env."""
        self.env.close()


def _make_env(config: dict[str, Any]) -> CoopLocMultiAgentEnv:
    return CoopLocMultiAgentEnv(config)


def ppo_config(
    env_config: dict[str, Any],
    *,
    seed: int = 0,
    num_env_runners: int = 0,
    rollout_fragment_length: int = 256,
    train_batch_size: int = 1024,
    minibatch_size: int = 256,
    num_epochs: int = 5,
    learning_rate: float = 3e-4,
    gamma: float = 0.99,
    ent_coef: float = 0.0,
    clip_range: float = 0.2,
    net_arch: tuple[int, ...] = (64, 64),
):
    """RLlib's ``PPOConfig`` for ``env_config``: one module shared by all agents, CPU only.

    Batch sizes count env steps of the whole team (RLlib's default), one
    learner in the driver process; ``num_env_runners=0`` samples in the driver.
    """
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.tune.registry import register_env

    register_env(ENV_NAME, _make_env)
    env_cfg = dict(env_config)
    scenario = env_cfg.pop("scenario", "outdoor_terrain")
    env_cfg.pop("render_mode", None)
    connector = None
    if coop_loc_env.make_config(scenario, **env_cfg).obs_format == "dict":
        from ray.rllib.connectors.env_to_module import FlattenObservations

        def connector(env, spaces=None, device=None):  # the default encoders take vectors
            return FlattenObservations(multi_agent=True)
    return (
        PPOConfig()
        # RLlib's env check wants a step's observations only from agents still live after
        # it, but an agent that just terminated has its last observation there too.
        .environment(ENV_NAME, env_config=dict(env_config), disable_env_checking=True)
        .framework("torch")
        .env_runners(
            num_env_runners=num_env_runners,
            num_envs_per_env_runner=1,
            num_cpus_per_env_runner=1,
            rollout_fragment_length=rollout_fragment_length,
            env_to_module_connector=connector,
        )
        .learners(num_learners=0, num_gpus_per_learner=0)
        .multi_agent(
            policies={MODULE_ID},
            policy_mapping_fn=lambda agent_id, *args, **kwargs: MODULE_ID,
        )
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=list(net_arch)))
        .training(
            train_batch_size_per_learner=train_batch_size,
            minibatch_size=minibatch_size,
            num_epochs=num_epochs,
            lr=learning_rate,
            gamma=gamma,
            entropy_coeff=ent_coef,
            clip_param=clip_range,
        )
        .debugging(seed=seed)
    )


@dataclasses.dataclass
class RLlibRun:
    """Settings of an RLlib run beyond the env (``scripts/train.py --backend rllib``)."""

    out: str
    scenario: str = "outdoor_terrain"
    overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    timesteps: int = 100_000  # agent steps, as in the stable-baselines3 path
    seed: int = 0
    num_env_runners: int = 1
    address: str | None = None
    train_batch_size: int = 1024
    minibatch_size: int = 256
    num_epochs: int = 5
    learning_rate: float = 3e-4
    gamma: float = 0.99
    ent_coef: float = 0.0
    clip_range: float = 0.2
    net_arch: tuple[int, ...] = (64, 64)
    checkpoint_freq: int = 50_000
    max_wall_s: float | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` naming a bad field (the env config included)."""
        for key in ("timesteps", "train_batch_size", "minibatch_size", "num_epochs"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be a positive integer, got {value!r}")
        for key in ("num_env_runners", "checkpoint_freq"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f"{key} must be a non-negative integer, got {value!r}")
        if self.minibatch_size > self.train_batch_size:
            raise ValueError(
                f"minibatch_size {self.minibatch_size} exceeds train_batch_size "
                f"{self.train_batch_size}"
            )
        coop_loc_env.make_config(self.scenario, **self.overrides)

    def env_config(self) -> dict[str, Any]:
        """RLlib's ``env_config``: the scenario and its overrides."""
        return {"scenario": self.scenario, **self.overrides}

    def config(self):
        """The ``PPOConfig`` of this run."""
        return ppo_config(
            self.env_config(), seed=self.seed, num_env_runners=self.num_env_runners,
            rollout_fragment_length=max(1, self.train_batch_size // max(1, self.num_env_runners)),
            train_batch_size=self.train_batch_size, minibatch_size=self.minibatch_size,
            num_epochs=self.num_epochs, learning_rate=self.learning_rate, gamma=self.gamma,
            ent_coef=self.ent_coef, clip_range=self.clip_range, net_arch=self.net_arch,
        )


def run_from_train_config(
    cfg: Any, num_env_runners: int | None = None, address: str | None = None
) -> RLlibRun:
    """The :class:`RLlibRun` of a :class:`policies.learning.training.TrainConfig` (``train.py``'s
    options); raises ``ValueError`` on an option the RLlib path does not have.

    One PPO update uses ``n_steps * n_envs`` env steps of the team, as in the
    stable-baselines3 path; ``batch_size`` is the minibatch.
    """
    unsupported = {
        "algo": (cfg.algo.upper(), "PPO"), "bc_from": (cfg.bc_from, None),
        "reward_mode": (cfg.reward_mode, "env"), "resume": (cfg.resume, None),
        "n_procs": (cfg.n_procs, 1),
    }
    for key, (value, default) in unsupported.items():
        if value != default:
            raise ValueError(
                f"--backend rllib does not support {key}={value!r} (env runners replace "
                f"--n-procs: use --num-env-runners)"
                if key == "n_procs" else f"--backend rllib does not support {key}={value!r}"
            )
    overrides = cfg.env_overrides()
    return RLlibRun(
        out=cfg.out, scenario=cfg.scenario, overrides=overrides, timesteps=cfg.timesteps,
        seed=cfg.seed, num_env_runners=1 if num_env_runners is None else num_env_runners,
        address=address, train_batch_size=cfg.n_steps * cfg.n_envs,
        minibatch_size=min(cfg.batch_size, cfg.n_steps * cfg.n_envs), num_epochs=cfg.n_epochs,
        learning_rate=cfg.learning_rate, gamma=cfg.gamma, ent_coef=cfg.ent_coef,
        clip_range=cfg.clip_range, net_arch=tuple(cfg.net_arch),
        checkpoint_freq=cfg.checkpoint_freq, max_wall_s=cfg.max_wall_s,
    )


def _scalars(result: dict, prefix: str = "") -> dict[str, float]:
    """The finite numeric leaves of an RLlib result dict, keyed ``a/b/c``."""
    out: dict[str, float] = {}
    for key, value in result.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_scalars(value, name + "/"))
        elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
            value, bool
        ) and np.isfinite(value):
            out[name] = float(value)
    return out


def agent_steps(result: dict) -> int:
    """Agent steps sampled so far (one per robot per env step), from an RLlib result."""
    value = result["env_runners"]["num_agent_steps_sampled_lifetime"]
    return int(sum(value.values()) if isinstance(value, dict) else value)


def train_rllib(run: RLlibRun) -> dict[str, Any]:
    """Train PPO with RLlib until ``run.timesteps`` agent steps; returns the summary.

    Starts local Ray (``num_cpus`` = env runners + 1) unless ``run.address``
    names a running cluster, and shuts Ray down at the end.
    """
    run.validate()
    import ray
    from torch.utils.tensorboard import SummaryWriter

    out = Path(run.out)
    out.mkdir(parents=True, exist_ok=True)
    settings = {**dataclasses.asdict(run), "backend": "rllib", "net_arch": list(run.net_arch)}
    (out / "train_config.json").write_text(json.dumps(settings, indent=2))
    started_ray = not ray.is_initialized()
    if started_ray:
        # Fixed string hashing in the env runners: RLlib iterates sets of agent ids, whose
        # order would otherwise differ between processes (and so the seeded samples).
        runtime_env = {"env_vars": {"PYTHONHASHSEED": "0"}}
        if run.address:
            ray.init(address=run.address, log_to_driver=False, runtime_env=runtime_env)
        else:
            ray.init(address="local", num_cpus=run.num_env_runners + 1, include_dashboard=False,
                     log_to_driver=False, configure_logging=False, runtime_env=runtime_env)
    set_torch_threads()  # the learner's updates in this process (coop_loc_env.threads)
    t0 = time.perf_counter()
    writer = SummaryWriter(str(out / "tb"))
    history: list[dict[str, float]] = []
    next_checkpoint = run.checkpoint_freq
    algo = None
    try:
        algo = run.config().build_algo()
        steps, t_train = 0, time.perf_counter()
        while steps < run.timesteps:
            result = algo.train()
            steps = agent_steps(result)
            scalars = _scalars(result)
            for key, value in scalars.items():
                if not key.startswith(("config/", "perf/", "pid", "timestamp")):
                    writer.add_scalar(key, value, steps)
            history.append({"agent_steps": steps, **{
                name: scalars.get(key, float("nan")) for name, key in HISTORY_KEYS.items()}})
            if run.checkpoint_freq and steps >= next_checkpoint:
                algo.save_to_path(str((out / "checkpoints" / f"agent_steps_{steps}").resolve()))
                next_checkpoint = steps + run.checkpoint_freq
            if run.max_wall_s is not None and time.perf_counter() - t0 > run.max_wall_s:
                break
        wall = time.perf_counter() - t_train
        algo.save_to_path(str((out / CHECKPOINT).resolve()))
    finally:
        writer.close()
        if algo is not None:
            algo.stop()
        if started_ray:
            ray.shutdown()
    summary = {
        "backend": "rllib", "timesteps": steps, "iterations": len(history),
        "wall_s": wall, "total_wall_s": time.perf_counter() - t0,
        "steps_per_s": steps / wall if wall > 0 else float("nan"),
        "checkpoint": str(out / CHECKPOINT), "history": history,
    }
    (out / "train_summary.json").write_text(json.dumps(summary, indent=2))
    return summary


class RLlibPolicy:
    """The shared network of an RLlib run, acting deterministically (its mean action).

    Args:
        path: a run ``DIR`` (its ``checkpoint``) or an algorithm checkpoint directory.
    """

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        if not is_rllib_run(path):
            raise ValueError(f"{str(path)!r} is not an RLlib run directory or checkpoint")
        ckpt = path / CHECKPOINT if (path / CHECKPOINT).is_dir() else path
        module_dir = ckpt.joinpath(*MODULE_PATH)
        if not module_dir.is_dir():
            raise ValueError(f"no module {MODULE_ID!r} in the RLlib checkpoint {str(ckpt)!r}")
        from ray.rllib.core.rl_module.rl_module import RLModule

        set_torch_threads(INFERENCE_THREADS)  # one team observation per forward pass
        self.module = RLModule.from_checkpoint(str(module_dir.resolve()))
        self.module.eval()
        self.name = path.name
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env``; the observation shape must match the network's."""
        check_observation_shape(self.name, self.module.observation_space.shape, env)
        self.env = env

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent (the Gaussian's mean, clipped to ``[-1, 1]``)."""
        import torch

        agents = list(self.env.agents)
        if not agents:
            return {}
        batch = torch.as_tensor(np.stack([obs[a] for a in agents]), dtype=torch.float32)
        with torch.no_grad():
            logits = self.module.forward_inference({"obs": batch})["action_dist_inputs"]
        dist = self.module.get_inference_action_dist_cls().from_logits(logits)
        actions = dist.to_deterministic().sample().numpy().astype(np.float32)
        return dict(zip(agents, np.clip(actions, -1.0, 1.0), strict=True))
