"""coop-loc-env: a PettingZoo multi-robot environment for cooperative localization and mapping.

Quick start::

    import coop_loc_env

    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=3, max_cycles=200)
    obs, infos = env.reset(seed=0)
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)

Every scenario is also registered with PettingZoo's registry under the
namespace ``coop_loc`` (``import coop_loc_env`` first)::

    pettingzoo.make("parallel", "coop_loc/OutdoorTerrain-v0")
"""

from __future__ import annotations

from typing import Any

from pettingzoo.env_registry import register
from pettingzoo.utils import wrappers

from coop_loc_env.aec import CoopLocAECEnv
from coop_loc_env.backends import register_backend
from coop_loc_env.config import Obstacle, RobotSpec, ScenarioConfig
from coop_loc_env.env import CoopLocParallelEnv
from coop_loc_env.obs_blocks import ObsBlock, register_obs_block
from coop_loc_env.rewards import RewardTerm, register_reward_term
from coop_loc_env.scenarios import (
    Scenario,
    describe_scenario,
    list_scenarios,
    make_config,
    register_scenario,
    unregister_scenario,
)
from coop_loc_env.vector import CoopLocVectorEnv

__version__ = "0.1.0"
REGISTRY_NAMESPACE = "coop_loc"

__all__ = [
    "CoopLocAECEnv",
    "CoopLocParallelEnv",
    "CoopLocVectorEnv",
    "ObsBlock",
    "Obstacle",
    "RewardTerm",
    "RobotSpec",
    "Scenario",
    "ScenarioConfig",
    "describe_scenario",
    "env",
    "env_id",
    "list_scenarios",
    "make_config",
    "parallel_env",
    "raw_env",
    "register_backend",
    "register_obs_block",
    "register_reward_term",
    "register_scenario",
    "torchrl_env",
    "unregister_scenario",
    "vector_env",
]


def parallel_env(
    scenario: str = "outdoor_terrain", render_mode: str | None = None, **overrides: Any
) -> CoopLocParallelEnv:
    """The parallel environment for ``scenario`` (any config field overridable by keyword)."""
    return CoopLocParallelEnv(scenario=scenario, render_mode=render_mode, **overrides)


def vector_env(
    scenario: str = "outdoor_terrain", num_envs: int = 1, **overrides: Any
) -> CoopLocVectorEnv:
    """``num_envs`` independent worlds of ``scenario`` stepped as one batch, on arrays
    ``(num_envs, n_robots, ...)`` (:mod:`coop_loc_env.vector`: seeding, autoreset, infos)."""
    return CoopLocVectorEnv(scenario, num_envs=num_envs, **overrides)


def raw_env(scenario: str = "outdoor_terrain", render_mode: str | None = None, **overrides: Any):
    """The AEC environment (PettingZoo's ``parallel_to_aec`` conversion that checks each
    agent's action when it is given), without the order-enforcing wrapper."""
    return CoopLocAECEnv(parallel_env(scenario, render_mode=render_mode, **overrides))


def env(scenario: str = "outdoor_terrain", render_mode: str | None = None, **overrides: Any):
    """The AEC environment with PettingZoo's standard order-enforcing wrapper."""
    return wrappers.OrderEnforcingWrapper(raw_env(scenario, render_mode=render_mode, **overrides))


def torchrl_env(
    scenario: str = "outdoor_terrain",
    seed: int | None = None,
    device: str = "cpu",
    num_envs: int | None = None,
    **overrides: Any,
):
    """The TorchRL environment of ``scenario``, ready for a collector.

    With ``num_envs=B``: ``B`` worlds as one batch, ``batch_size=[B]``
    (:class:`coop_loc_env.torchrl_vector.CoopLocTorchRLVectorEnv`, the layout below with
    a batch dimension in front, as TorchRL's ``VmasEnv``; world ``i`` seeded ``seed + i``).

    A native ``torchrl.envs.EnvBase`` (:class:`coop_loc_env.native_torchrl.CoopLocTorchRLEnv`)
    that steps the team as one batch: group ``robot`` with ``observation``, ``action``,
    ``reward``, per-robot ``done``/``terminated``/``truncated`` and ``mask``, and the scalar
    infos under ``(robot, info)`` (``info_keys=[...]`` picks them). Any config field is
    overridable by keyword. Sets torch's thread count to the project's
    (:mod:`coop_loc_env.threads`; ``COOP_LOC_TORCH_THREADS=0`` leaves torch's own).
    Needs the ``torchrl`` extra.
    """
    from coop_loc_env.threads import set_torch_threads

    set_torch_threads()
    if num_envs is not None:
        from coop_loc_env.torchrl_vector import make_torchrl_vector_env

        return make_torchrl_vector_env(scenario, num_envs, seed=seed, device=device,
                                       **overrides)
    from coop_loc_env.native_torchrl import make_torchrl_env

    return make_torchrl_env(scenario, seed=seed, device=device, **overrides)


def env_id(scenario: str) -> str:
    """PettingZoo registry id of ``scenario``, e.g. ``coop_loc/OutdoorTerrain-v0``."""
    camel = "".join(part.capitalize() for part in scenario.split("_"))
    return f"{REGISTRY_NAMESPACE}/{camel}-v0"


def _register_all() -> None:
    for name in list_scenarios():
        register("parallel", env_id(name), entry_point=parallel_env, kwargs={"scenario": name})
        register("aec", env_id(name), entry_point=env, kwargs={"scenario": name})


_register_all()
