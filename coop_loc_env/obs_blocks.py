"""Observation blocks registered by name: the parts an observation is made of.

A block has a name, a size (columns of the observation vector) and entry names
given the config and the belief size, and fills its columns for every robot at
once (:meth:`ObsBlock.observe`). The env's observation is the blocks named by
:func:`block_names`, in that order: the shipped flat vector
(:mod:`coop_loc_env.observations`), then the config's ``extra_obs_blocks``; with
``obs_format="dict"`` the vector ends with ``belief_modes`` and the ``belief_map``
block is an entry of its own (:mod:`coop_loc_env.belief_map`). Every vector entry
is clipped to ``[-OBS_LIMIT, OBS_LIMIT]``. A block from outside the package::

    @register_obs_block("speed_limit")
    class SpeedLimit(ObsBlock):
        def __init__(self, setup):
            super().__init__(setup, ["max_speed"])
        def observe(self, x, out):
            out[:, 0] = x.env.world.max_speed

    env = coop_loc_env.parallel_env(extra_obs_blocks=("speed_limit",))
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from gymnasium import spaces

OBS_LIMIT = 10.0


@dataclass(frozen=True)
class ObsSetup:
    """What a block is built from: the config, the belief block's size and entry names
    (the estimator features, zero-padded), the world (the known map) and the
    :class:`~coop_loc_env.observations.ObservationBuilder` (its latched readings)."""

    cfg: Any
    belief_size: int
    belief_names: tuple[str, ...] = ()
    world: Any = None
    builder: Any = None


@dataclass(slots=True)
class ObsInputs:
    """What the blocks read at one step, one row per robot: ``belief`` features
    ``(n, b)`` (``b <= belief_size``), the ``last_action`` ``(n, 2)``, ``true_poses``
    (privileged blocks only), the shared estimates ``est_mean`` / ``est_cov``, the
    ``active`` robots, and the ``env`` (its public parts: ``mapper``, ``sensors``...)."""

    belief: np.ndarray
    last_action: np.ndarray
    true_poses: np.ndarray
    est_mean: np.ndarray
    est_cov: np.ndarray
    active: np.ndarray
    env: Any = None
    _memo: dict = field(default_factory=dict)

    def shared(self, key: str, make: Callable[[], Any]) -> Any:
        """``make()``, computed once per step for every block that asks for ``key``."""
        if key not in self._memo:
            self._memo[key] = make()
        return self._memo[key]


class ObsBlock:
    """One observation block; ``cls(setup)`` builds it (:class:`ObsSetup`).

    A vector block (``entry = None``) fills ``out`` ``(n, size)`` float32 columns; a
    block with an ``entry`` name is that entry of the dict observation
    (``obs_format="dict"`` only) and fills ``out`` of its :meth:`space`'s shape per robot.
    """

    name: str = ""
    entry: str | None = None

    def __init__(self, setup: ObsSetup, names: list[str]) -> None:
        self.setup = setup
        self.names = list(names)
        self.size = len(self.names)

    def space(self) -> spaces.Box:
        """The block's space (a vector block: ``Box(-OBS_LIMIT, OBS_LIMIT, (size,))``)."""
        return spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(self.size,), dtype=np.float32)

    def reset(self) -> None:
        """Start of an episode (blocks with state forget it)."""

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        """Fill ``out`` (every robot's rows of this block) from ``x``."""
        raise NotImplementedError


BlockFactory = Callable[[ObsSetup], ObsBlock]
#: Block name -> factory ``factory(setup) -> ObsBlock`` (a class or a function), or a
#: ``"module:attr"`` path to one, imported when a config first uses the block.
OBS_BLOCKS: dict[str, BlockFactory | str] = {
    "belief_modes": "coop_loc_env.belief_map:modes_block",
    "belief_map": "coop_loc_env.belief_map:map_block",
}


def register_obs_block(name: str, factory: BlockFactory | str | None = None) -> Any:
    """Make ``factory`` available as observation block ``name`` (a decorator without it)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"an observation block name must be a non-empty string, got {name!r}")

    def register(f: BlockFactory | str) -> BlockFactory | str:
        OBS_BLOCKS[name] = f
        if isinstance(f, type) and issubclass(f, ObsBlock):
            f.name = name
        return f

    return register if factory is None else register(factory)


def make_block(name: str, setup: ObsSetup) -> ObsBlock:
    """Build the block registered as ``name``."""
    check_obs_blocks((name,))
    factory = OBS_BLOCKS[name]
    if isinstance(factory, str):
        module, _, attr = factory.partition(":")
        factory = OBS_BLOCKS[name] = getattr(importlib.import_module(module), attr)
    block = factory(setup)
    block.name = name
    return block


def check_obs_blocks(names: Any) -> None:
    """Raise ``ValueError`` naming an entry of ``names`` that is no registered block."""
    if not isinstance(names, tuple) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"extra_obs_blocks must be a list of block names, got {names!r}")
    for name in names:
        if name not in OBS_BLOCKS:
            raise ValueError(f"unknown observation block {name!r}; registered: "
                             f"{', '.join(OBS_BLOCKS)} (register_obs_block)")


#: The blocks of every flat observation, in order (the sensor blocks' columns are the
#: builder's latched readings).
CORE_BLOCKS = ("belief", "gps", "inclinometer", "range", "detections", "last_action")


def block_names(cfg: Any) -> tuple[str, ...]:
    """The blocks of ``cfg``'s observation, in order (module docstring)."""
    names = list(CORE_BLOCKS)
    if cfg.teammate_obs:
        names.append("teammates")
    if cfg.map_patch_obs:
        names.append("map_patch")
    if cfg.privileged_obs:
        names.append("privileged")
    names += cfg.extra_obs_blocks
    if cfg.obs_format == "dict":
        names += ["belief_modes", "belief_map"]
    return tuple(names)
