"""BenchMARL tasks for every registered scenario: ``CoopLocTask.RENDEZVOUS`` and so on.

::

    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig
    from coop_loc_env.benchmarl import CoopLocTask

    task = CoopLocTask.RENDEZVOUS.get_from_yaml()   # the YAML shipped in this package
    Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(),
               model_config=MlpConfig.get_from_yaml(), seed=0,
               config=ExperimentConfig.get_from_yaml()).run()

or from the command line (the package's hydra plugin puts its task YAML on BenchMARL's
search path; nothing is copied into site-packages)::

    python -m benchmarl.run algorithm=mappo task=coop_loc/rendezvous
    python -m benchmarl.run algorithm=mappo task=coop_loc/rendezvous experiment=coop_loc_short

(``experiment=coop_loc_short``: a run of about a minute on 2 cores). Every task's
``defaults:`` list makes BenchMARL log to CSV files only (its default adds wandb;
``experiment.loggers=[csv,wandb]`` brings it back) and adds a hydra callback that stops
the run with one line if a logger's package is missing. The env sets torch's thread
count to the project's (:mod:`coop_loc_env.threads`).

Each task's YAML (``coop_loc_env/benchmarl/conf/task/coop_loc/<scenario>.yaml``) holds
:class:`~coop_loc_env.config.ScenarioConfig` overrides (``team`` as a list of dicts) and
its hydra ``defaults:`` list.
The env is the batched TorchRL env (:mod:`coop_loc_env.torchrl_vector`, group ``robot``):
BenchMARL's ``num_envs`` worlds in one env with ``batch_size=[num_envs]``, as its VMAS
tasks (no ``SerialEnv`` of copies);
its infos are logged as NaN-aware means (:meth:`CoopLocClass.log_info`): position
error, particle spread (MCL robots only), coverage, map RMSE, and the steps a robot
takes to get within 1.5 m of its true position. BenchMARL's losses do not read the
per-robot ``mask``: a robot that tipped over (scenarios with steep patches, e.g.
``outdoor_terrain``) feeds zero observations and rewards into the loss until the
episode ends; ``rendezvous``, ``active_hallway`` and the hallway scenarios have none.
Needs the ``benchmarl`` extra.
"""

from __future__ import annotations

import copy
import importlib.resources
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from benchmarl.environments import Task, TaskClass, task_config_registry
from benchmarl.utils import _read_yaml_config
from tensordict import TensorDictBase
from torchrl.data import Composite
from torchrl.envs import EnvBase

from coop_loc_env.env import CoopLocParallelEnv
from coop_loc_env.native_torchrl import DEFAULT_INFO_KEYS, GROUP, CoopLocTorchRLEnv
from coop_loc_env.scenarios import make_config
from coop_loc_env.threads import set_torch_threads
from coop_loc_env.torchrl_vector import CoopLocTorchRLVectorEnv, make_torchrl_vector_env

#: BenchMARL's environment name of these tasks (``task=coop_loc/<scenario>``).
ENV_NAME = "coop_loc"
#: The group entry holding the infos (not ``info``: BenchMARL would average NaNs).
INFO_NAME = "coop_info"
#: A robot is localized within this many metres of its true position (Fox et al.).
LOCALIZED_M = 1.5
#: The folder of the package's hydra configs (``task/coop_loc/<scenario>.yaml``).
CONF_DIR = Path(str(importlib.resources.files(__name__) / "conf"))


class CoopLocClass(TaskClass):
    """A coop_loc_env scenario as a BenchMARL task (continuous actions, one group)."""

    @property
    def scenario(self) -> str:
        """The scenario name (the task's name, lower case)."""
        return self.name.lower()

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        if not continuous_actions:
            raise ValueError(
                f"coop_loc tasks have continuous actions only; {self.name} got "
                f"continuous_actions={continuous_actions!r}"
            )
        config = copy.deepcopy(dict(self.config))
        scenario = self.scenario
        set_torch_threads()  # the project's torch threads for this run (coop_loc_env.threads)
        probe = CoopLocParallelEnv(scenario=scenario, **config)  # its estimators' infos
        probe.reset(seed=0)
        extra = [k for entries in probe.extra_infos().values() for k in entries]
        keys = tuple(dict.fromkeys([*DEFAULT_INFO_KEYS, *extra]))
        return lambda: make_torchrl_vector_env(
            scenario, num_envs, seed=seed, device=device, info_keys=keys,
            info_name=INFO_NAME, **copy.deepcopy(config),
        )

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        return make_config(self.scenario, **self.config).max_cycles

    def group_map(self, env: EnvBase) -> dict[str, list[str]]:
        return {GROUP: list(_base(env).agents)}

    def observation_spec(self, env: EnvBase) -> Composite:
        spec = env.full_observation_spec_unbatched[GROUP]  # one world's (as VMAS tasks)
        return Composite({GROUP: Composite(observation=spec["observation"].clone(),
                                           shape=spec.shape)})

    def info_spec(self, env: EnvBase) -> Composite | None:
        spec = env.full_observation_spec_unbatched[GROUP]
        return Composite({GROUP: Composite({INFO_NAME: spec[INFO_NAME].clone()},
                                           shape=spec.shape)})

    def state_spec(self, env: EnvBase) -> Composite | None:
        return None

    def action_mask_spec(self, env: EnvBase) -> Composite | None:
        return None

    def action_spec(self, env: EnvBase) -> Composite:
        return env.full_action_spec_unbatched

    @staticmethod
    def env_name() -> str:
        return ENV_NAME

    @staticmethod
    def log_info(batch: TensorDictBase) -> dict[str, float]:
        """NaN-aware means of the collected infos (robots without a figure are left out)."""
        info = batch.get(("next", GROUP, INFO_NAME), None)
        if info is None:
            return {}
        out = {}
        for key in ("position_error", "particle_spread", "coverage", "map_rmse"):
            if key in info.keys():
                value = torch.nanmean(info.get(key).to(torch.float)).item()
                if value == value:  # every robot NaN (no MCL robot): nothing to log
                    out[f"collection/{GROUP}/info/{key}"] = value
        if "position_error" in info.keys():
            steps = _steps_to_localize(info.get("position_error"),
                                       batch.get(("next", "done")))
            if steps is not None:
                out[f"collection/{GROUP}/info/steps_to_localize"] = steps
        return out


class CoopLocTask(Task):
    """The shipped coop_loc_env scenarios as BenchMARL tasks (YAML in this package)."""

    ACTIVE_HALLWAY = None
    ACTIVE_LATTICE = None
    CIRCUIT = None
    DGPS_OUTAGE = None
    DISPERSAL = None
    HEXAGON = None
    OUTDOOR_TERRAIN = None
    RENDEZVOUS = None
    SYMMETRIC_HALLWAY = None

    @staticmethod
    def associated_class():
        return CoopLocClass

    def get_from_yaml(self, path: str | None = None) -> TaskClass:
        """The task with its config from ``path``, by default the YAML in this package."""
        if path is None:
            path = str(CONF_DIR / "task" / ENV_NAME / f"{self.name.lower()}.yaml")
        config = _read_yaml_config(path)
        config.pop("defaults", None)  # hydra's defaults list: experiment settings, not the env's
        return self.get_task(config=config)


def _base(env: EnvBase) -> CoopLocTorchRLEnv | CoopLocTorchRLVectorEnv:
    """The env of this package under BenchMARL's transforms."""
    while not isinstance(env, (CoopLocTorchRLEnv, CoopLocTorchRLVectorEnv)):
        env = env.base_env
    return env


def _steps_to_localize(error: torch.Tensor, done: torch.Tensor) -> float | None:
    """Mean steps from an episode's start until a robot's position error is first within
    :data:`LOCALIZED_M`, over the robots of the episodes that start inside the batch
    (a robot that never gets there counts its episode's length); ``None`` if none does.

    ``error`` is ``(..., T, n)``, ``done`` ``(..., T, 1)`` (the team's done after each step).
    """
    err = error.reshape(-1, *error.shape[-2:])
    ends = done.reshape(-1, done.shape[-2])
    times = []
    for e, d in zip(err, ends, strict=True):
        stops = torch.nonzero(d).flatten().tolist()
        for start, stop in zip(stops[:-1], stops[1:], strict=True):
            seg = e[start + 1 : stop + 1]  # the steps of one whole episode
            within = seg <= LOCALIZED_M
            steps = torch.where(within.any(0), within.float().argmax(0) + 1, len(seg))
            times.extend(steps.tolist())
    return float(sum(times) / len(times)) if times else None


def register() -> None:
    """Add the tasks to BenchMARL's registry (``task=coop_loc/<scenario>`` in hydra)."""
    for task in CoopLocTask:
        task_config_registry[f"{ENV_NAME}/{task.name.lower()}"] = task


register()
