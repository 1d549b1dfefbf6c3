"""Many worlds of one scenario stepped by one call, on arrays ``(num_envs, n_robots, ...)``.

:func:`coop_loc_env.vector_env` builds a :class:`CoopLocVectorEnv`: ``B`` independent
worlds of one scenario (same config, each its own random stream). ``reset(seed=s)``
seeds world ``i`` with ``s + i``, so world ``i`` replays ``parallel_env(...)`` reset
with ``seed=s + i`` exactly under the same actions. ``step(actions)`` takes an array
``(B, n, 2)`` and returns

- observations ``(B, n, obs_dim)`` float32 (with ``obs_format="dict"`` a dict of such
  arrays, one per entry of the observation space: ``vector``, ``belief_map``...),
- rewards ``(B, n)``, terminated and truncated ``(B, n)`` bool,
- infos: a dict of arrays ``(B, n, ...)``; always ``mask`` (the robot acted in this step:
  its reward and flags are real, as TorchRL's ``mask``), ``position_error``,
  ``heading_error``, ``collisions``, ``in_contact``, ``tipped_over`` and every reward term
  as ``reward_<term>``; the others of the parallel env's infos (``true_pose``,
  ``est_pose``, ``pose_cov``, ``gps_fix``, ``satellites``, ``new_cells``,
  ``covered_cells``, ``coverage``, ``map_rmse``, the estimators' own entries) cost more
  and are reported when named in ``info_keys``.

Robots that tipped over (``tip_over_terminates``) stay in their rows: their ``mask`` is
False from the next step on, their actions are ignored (not checked) and their rewards
are 0; ``terminated`` stays True for them until their world resets.

**Autoreset, same step.** A world whose episode ends in a step (every robot terminated,
or ``max_cycles`` reached) is reset at once, continuing its own random stream (as
``parallel_env.reset()`` without a seed): the observations returned for it are the new
episode's first ones, and its final observations are in ``infos["final_obs"]`` (the
array of all worlds, or a dict of them; rows of worlds that did not end are zeros) with
``infos["_final_obs"]`` ``(B,)`` saying which worlds ended (Gymnasium's same-step
autoreset, as SB3's VecEnv expects). Rewards, flags and the other infos of that row are
those of the step that ended the episode. ``reset_count`` counts each world's resets.
With ``autoreset=False`` an ended world waits for ``reset(worlds=...)`` (TorchRL's
convention: the collector resets the worlds its ``_reset`` mask names).

**Structure.** Each world is a :class:`~coop_loc_env.env.CoopLocParallelEnv` whose
array core (``step_core``: physics, sensors, estimators, team map, reward terms, one
:class:`~coop_loc_env.records.StepRecord`) the parallel env runs too; the vector env
stacks the records and builds the observations, skipping the per-agent dicts.

A bad action is refused with a ``ValueError`` naming its world and robot before any
world moves, so the batch stays usable.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import batch_space

from coop_loc_env.actions import ACTION_TOLERANCE
from coop_loc_env.env import CoopLocParallelEnv
from coop_loc_env.records import StepRecord

#: The infos every step reports, besides ``mask`` and the reward terms (``reward_<term>``).
DEFAULT_INFO_KEYS = ("position_error", "heading_error", "collisions", "in_contact",
                     "tipped_over")
#: The parallel env's other info keys, reported when named in ``info_keys``.
OPT_IN_INFO_KEYS = ("true_pose", "est_pose", "pose_cov", "gps_fix", "satellites",
                    "new_cells", "covered_cells", "coverage", "map_rmse")


class CoopLocVectorEnv:
    """``num_envs`` worlds of ``scenario`` stepped as one batch (module docstring).

    Args:
        scenario: a registered scenario name.
        num_envs: the number of worlds ``B`` (>= 1).
        info_keys: the infos to report besides ``mask``; default :data:`DEFAULT_INFO_KEYS`
            and the reward terms. Unknown names are refused at :meth:`reset`.
        autoreset: reset a world in the step that ends it (default); with False an ended
            world waits for ``reset(worlds=...)`` (TorchRL's ``_reset`` mask) and a step
            before it is refused.
        **overrides: any config field, as for :func:`coop_loc_env.parallel_env`.
    """

    def __init__(self, scenario: str = "outdoor_terrain", num_envs: int = 1,
                 info_keys: tuple[str, ...] | list[str] | None = None,
                 autoreset: bool = True, **overrides: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or (
                num_envs < 1):
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        if info_keys is not None and (isinstance(info_keys, str) or not all(
                isinstance(k, str) for k in info_keys)):
            raise ValueError(f"info_keys must be a list of info names, got {info_keys!r}")
        if not isinstance(autoreset, bool):
            raise ValueError(f"autoreset must be True or False, got {autoreset!r}")
        self.scenario = scenario
        self.autoreset = autoreset
        self.num_envs = int(num_envs)
        self.envs = [CoopLocParallelEnv(scenario, **overrides) for _ in range(self.num_envs)]
        first = self.envs[0]
        self.config = first.config
        self.n_robots = n = self.config.n_robots
        self.possible_agents = list(first.possible_agents)
        #: One robot's observation space (a ``Box`` or a ``Dict``) and action space.
        self.single_observation_space = first.observation_space(first.possible_agents[0])
        self.single_action_space = first.action_space(first.possible_agents[0])
        self.dict_obs = isinstance(self.single_observation_space, spaces.Dict)
        #: The spaces of the whole batch: ``(B, n, ...)`` (a ``Dict`` of them for dict
        #: observations) and the actions ``Box(-1, 1, (B, n, 2))``.
        self.observation_space = batch_space(batch_space(self.single_observation_space, n),
                                             self.num_envs)
        self.action_space = batch_space(batch_space(self.single_action_space, n),
                                        self.num_envs)
        self._requested = None if info_keys is None else tuple(info_keys)
        self.info_keys: tuple[str, ...] = ()
        self._mask = np.zeros((self.num_envs, n), dtype=bool)
        self._ended = np.zeros(self.num_envs, dtype=bool)
        self.reset_count = np.zeros(self.num_envs, dtype=np.int64)
        self._ready = False

    # ------------------------------------------------------------------ reset
    def reset(self, seed: Any = None, worlds: Any = None
              ) -> tuple[Any, dict[str, np.ndarray]]:
        """Start every world, or only ``worlds`` (indices or a ``(B,)`` bool mask): world
        ``i`` seeded with ``seed + i`` (or ``seed[i]`` given a list of ``B`` seeds;
        unseeded, continuing its stream, with ``None``). Returns every world's
        observations and the infos (``mask``)."""
        seeds = self._seeds(seed)
        rows = self._world_rows(worlds)
        if not self._ready and len(rows) < self.num_envs:
            raise ValueError("the first reset() starts every world: call it without worlds")
        for i in rows:
            self.envs[i].reset(seed=seeds[i])
        if not self._ready:
            self.info_keys = self._check_info_keys()
        self._mask[rows] = True
        self._ended[rows] = False
        self.reset_count[rows] += 1
        self._ready = True
        obs = self._observe()
        return obs, {"mask": self._mask.copy()}

    def _seeds(self, seed: Any) -> list[int | None]:
        """One seed per world: ``seed + i``, the given list, or ``None`` for each."""
        def bad(x: Any) -> bool:
            return isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < 0

        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (list, tuple, np.ndarray)):
            if len(seed) != self.num_envs or any(x is not None and bad(x) for x in seed):
                raise ValueError(f"a list of seeds needs one non-negative integer (or None) "
                                 f"per world ({self.num_envs}), got {seed!r}")
            return [None if x is None else int(x) for x in seed]
        if bad(seed):
            raise ValueError(f"seed must be a non-negative integer, a list of them or None, "
                             f"got {seed!r}")
        return [int(seed) + i for i in range(self.num_envs)]

    def _world_rows(self, worlds: Any) -> np.ndarray:
        """The indices of ``worlds`` (all with ``None``), checked."""
        if worlds is None:
            return np.arange(self.num_envs)
        w = np.asarray(worlds)
        if w.dtype == bool:
            if w.shape != (self.num_envs,):
                raise ValueError(f"a worlds mask must have shape ({self.num_envs},), "
                                 f"got {w.shape}")
            return np.flatnonzero(w)
        if w.dtype.kind not in "iu" or w.ndim != 1 or (
                w.size and not (0 <= w.min() and w.max() < self.num_envs)):
            raise ValueError(f"worlds must be indices in [0, {self.num_envs}) or a bool mask, "
                             f"got {worlds!r}")
        return w.astype(np.int64)

    def _check_info_keys(self) -> tuple[str, ...]:
        env = self.envs[0]
        terms = [f"reward_{name}" for name in env.reward_terms.names]
        extra = sorted({k for entries in env.extra_infos().values() for k in entries})
        if self._requested is None:
            return (*DEFAULT_INFO_KEYS, *terms)
        known = (*DEFAULT_INFO_KEYS, *terms, *OPT_IN_INFO_KEYS, *extra)
        unknown = [k for k in self._requested if k not in known]
        if unknown:
            raise ValueError(f"info_keys names {unknown}, not info keys of this env; "
                             f"its keys: {', '.join(known)}")
        return self._requested

    # ------------------------------------------------------------------ step
    def step(self, actions: Any):
        """Step every world by ``actions`` ``(B, n, 2)`` in ``[-1, 1]``; returns
        ``(obs, rewards, terminated, truncated, infos)`` (module docstring)."""
        act = self._check_actions(actions)
        if self._ended.any():
            raise ValueError(f"world {int(np.flatnonzero(self._ended)[0])} has ended and "
                             "autoreset is off: reset(worlds=...) it first")
        B, n = self.num_envs, self.n_robots
        mask = self._mask.copy()  # the robots that act in this step
        records: list[StepRecord] = []
        for b, env in enumerate(self.envs):
            records.append(env.step_core(act[b]))
        rewards = np.array([r.rewards for r in records], dtype=float).reshape(B, n)
        rewards[~mask] = 0.0
        truncated_world = np.fromiter((r.truncated for r in records), bool, B)
        alive = np.stack([env.active for env in self.envs])
        terminated = ~alive
        truncated = np.repeat(truncated_world[:, None], n, axis=1) & mask
        infos = self._infos(records, mask)
        ended = truncated_world | ~alive.any(axis=1)
        self._mask = alive & ~truncated_world[:, None]
        obs = self._observe()
        if ended.any() and not self.autoreset:
            self._ended |= ended
        elif ended.any():
            infos["final_obs"] = _zeros_like_rows(obs, ended)
            infos["_final_obs"] = ended
            for b in np.flatnonzero(ended):
                self.envs[b].reset()
                self._mask[b] = True
                self.reset_count[b] += 1
            self._fill_rows(obs, np.flatnonzero(ended))
        return obs, rewards, terminated, truncated, infos

    def _check_actions(self, actions: Any) -> np.ndarray:
        """Every action checked before any world moves: ``(B, n, 2)`` floats, clipped within
        the tolerance; rows of robots already out are zeroed and not checked."""
        if not self._ready:
            raise ValueError("step() called before reset(): call reset() first")
        B, n = self.num_envs, self.n_robots
        arr = actions if isinstance(actions, np.ndarray) else None
        if arr is None:
            try:
                arr = np.asarray(actions)
            except (TypeError, ValueError):
                raise ValueError(
                    f"actions must be an array of shape ({B}, {n}, 2), got "
                    f"{type(actions).__name__}") from None
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"actions must hold real numbers, got dtype {arr.dtype}")
        if arr.shape != (B, n, 2):
            raise ValueError(f"actions must have shape ({B}, {n}, 2), got {arr.shape}")
        act = arr.astype(float)
        act[~self._mask] = 0.0
        peak = np.abs(act).max()
        if not peak <= 1.0 + ACTION_TOLERANCE:  # NaN fails every comparison
            bad = ~(np.abs(act) <= 1.0 + ACTION_TOLERANCE).all(axis=2)
            b, i = np.argwhere(bad)[0]
            what = "contains NaN or inf" if not np.isfinite(act[b, i]).all() else (
                "is outside [-1, 1]")
            raise ValueError(f"action of robot {i} in world {b} {what}: {arr[b, i]!r}")
        if peak > 1.0:
            np.clip(act, -1.0, 1.0, out=act)
        return act

    # ------------------------------------------------------------------ outputs
    def _observe(self) -> Any:
        """Every world's observations, stacked."""
        B, n = self.num_envs, self.n_robots
        if self.dict_obs:
            out = {key: np.empty((B, n, *space.shape), dtype=np.float32)
                   for key, space in self.single_observation_space.spaces.items()}
        else:
            out = np.empty((B, n, *self.single_observation_space.shape), dtype=np.float32)
        self._fill_rows(out, range(B))
        return out

    def _fill_rows(self, out: Any, worlds: Any) -> None:
        """Write the current observations of ``worlds`` into their rows of ``out``."""
        for b in worlds:
            env = self.envs[int(b)]
            x = env.observation_inputs()
            builder = env.observations
            if not self.dict_obs:
                out[b] = builder.vectors(x)
                continue
            out["vector"][b] = builder.vectors(x)
            for block in builder.entry_blocks:
                block.observe(x, out[block.entry][b])

    def _infos(self, records: list[StepRecord], mask: np.ndarray) -> dict[str, np.ndarray]:
        """The step's infos as arrays ``(B, n, ...)``."""
        infos: dict[str, np.ndarray] = {"mask": mask}
        for key in self.info_keys:
            infos[key] = self._info(key, records)
        return infos

    def _info(self, key: str, records: list[StepRecord]) -> np.ndarray:
        B, n = self.num_envs, self.n_robots
        if key == "position_error":
            return np.stack([r.err_xy for r in records])
        if key == "heading_error":
            return np.stack([r.err_th for r in records])
        if key == "collisions":
            return np.stack([r.new_contacts for r in records]).astype(np.int64)
        if key == "in_contact":
            return np.stack([r.in_contact for r in records]).astype(bool)
        if key == "tipped_over":
            return np.stack([env.tipped for env in self.envs])
        if key.startswith("reward_") and key[7:] in records[0].terms:
            return np.array([r.terms[key[7:]] for r in records], dtype=float).reshape(B, n)
        if key in ("true_pose", "est_pose", "pose_cov"):
            return np.stack([getattr(r, key) for r in records])
        if key in ("gps_fix", "satellites"):
            name = "gps_mask" if key == "gps_fix" else "satellites"
            return np.stack([getattr(env.last_readings, name) for env in self.envs])
        if key == "new_cells":
            return np.stack([env.new_cells for env in self.envs])
        if key == "covered_cells":
            return np.stack([env.covered_cells for env in self.envs])
        if key in ("coverage", "map_rmse"):
            values = [getattr(env.mapper, key)() for env in self.envs]
            return np.repeat(np.asarray(values, dtype=float)[:, None], n, axis=1)
        out = np.full((B, n), np.nan)  # an estimator's own entry
        for b, env in enumerate(self.envs):
            for i, entries in env.extra_infos().items():
                out[b, i] = entries.get(key, np.nan)
        return out

    # ------------------------------------------------------------------ state
    @property
    def mask(self) -> np.ndarray:
        """``(B, n)``: the robots that act in the next step (a copy)."""
        return self._mask.copy()

    @property
    def estimated_poses(self) -> np.ndarray:
        """Every world's belief means ``(B, n, 3)``."""
        return np.stack([env.beliefs.mean for env in self.envs])

    @property
    def estimated_covariances(self) -> np.ndarray:
        """Every world's belief covariances ``(B, n, 3, 3)``."""
        return np.stack([env.beliefs.cov for env in self.envs])

    def close(self) -> None:
        """Release every world's renderer."""
        for env in self.envs:
            env.close()


def _zeros_like_rows(obs: Any, rows: np.ndarray) -> Any:
    """A copy of ``obs`` with only the worlds ``rows`` kept (others zero)."""
    if isinstance(obs, dict):
        return {key: _zeros_like_rows(value, rows) for key, value in obs.items()}
    out = np.zeros_like(obs)
    out[rows] = obs[rows]
    return out
