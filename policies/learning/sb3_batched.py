"""The stable-baselines3 ``VecEnv`` over one batched env (``coop_loc_env.vector_env``).

:class:`BatchedVecEnv` has the slots and episode conventions of
:class:`~policies.learning.sb3_vec_env.ParallelEnvVecEnv` (slot ``k * n + i`` is robot
``i`` of world ``k``; ``terminal_observation``, ``TimeLimit.truncated``, ``episode``,
padding slots of robots out early: :mod:`policies.learning.vec_env`), and the same
seeding (world ``k`` starts with the seed of its first slot, ``s + k * n``), so with the
same seed it samples exactly what the copies sample, without their per-agent dicts. The
slots' infos hold only those entries (not the env's per-robot infos). Importing this
module imports stable-baselines3 (the ``train`` extra).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

import coop_loc_env


class BatchedVecEnv(VecEnv):
    """SB3 ``VecEnv`` with one slot per robot of ``n_envs`` worlds of one batched env.

    Args:
        scenario: the scenario name.
        n_envs: the number of worlds (``num_envs = n_envs * n_robots`` slots).
        **overrides: config overrides, as for :func:`coop_loc_env.parallel_env`.
    """

    def __init__(self, scenario: str, n_envs: int = 1, **overrides: Any) -> None:
        if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
            raise ValueError(f"n_envs must be a positive integer, got {n_envs!r}")
        self.venv = coop_loc_env.vector_env(scenario, num_envs=n_envs, info_keys=(),
                                            **overrides)
        self.n_envs, self.n_agents = n_envs, self.venv.n_robots
        super().__init__(n_envs * self.n_agents, self.venv.single_observation_space,
                         self.venv.single_action_space)
        shape = (n_envs, self.n_agents)
        self.padding = np.zeros(shape, dtype=bool)  # robot done, world not yet reset
        self.ep_return = np.zeros(shape)
        self.ep_length = np.zeros(shape, dtype=np.int64)
        self.start_time = time.time()
        self._actions: np.ndarray | None = None

    def _flat(self, obs: Any) -> Any:
        """``(B, n, ...)`` -> ``(B * n, ...)`` (each entry of a dict observation)."""
        if isinstance(obs, dict):
            return {k: v.reshape(self.num_envs, *v.shape[2:]) for k, v in obs.items()}
        return obs.reshape(self.num_envs, *obs.shape[2:])

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> Any:
        """Reset every world, seeding world ``k`` with the seed of its first slot."""
        seeds = [self._seeds[k * self.n_agents] for k in range(self.n_envs)]
        obs, _ = self.venv.reset(seed=seeds)
        self.padding[:] = False
        self.ep_return[:] = 0.0
        self.ep_length[:] = 0
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return self._flat(obs)

    def step_async(self, actions: np.ndarray) -> None:
        """Keep the actions ``(num_envs, 2)`` for :meth:`step_wait`."""
        self._actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, -1)

    def step_wait(self) -> VecEnvStepReturn:
        """Observations, rewards, dones and infos of every slot."""
        if self._actions is None:
            raise ValueError("step_wait() called before step_async()")
        space = self.action_space
        act = np.clip(self._actions, space.low, space.high).reshape(self.n_envs,
                                                                    self.n_agents, -1)
        self._actions = None
        live = self.venv.mask  # the robots that act in this step
        obs, rewards, term, trunc, infos = self.venv.step(act)
        ended = infos.get("_final_obs", np.zeros(self.n_envs, dtype=bool))
        last = infos.get("final_obs")
        done = (term | trunc) & live
        self.ep_return += np.where(live, rewards, 0.0)
        self.ep_length += live
        slot_infos: list[dict] = [{} for _ in range(self.num_envs)]
        out_obs = obs if not done.any() else _copy(obs)
        for k, i in np.argwhere(done):
            final = obs if not ended[k] else last
            slot_infos[k * self.n_agents + i] = {
                "terminal_observation": _row(final, k, i),
                "TimeLimit.truncated": bool(trunc[k, i] and not term[k, i]),
                "episode": {"r": float(self.ep_return[k, i]), "l": int(self.ep_length[k, i]),
                            "t": round(time.time() - self.start_time, 6)},
            }
            if not ended[k]:  # a robot out early: a padding slot until its world resets
                self.padding[k, i] = True
                _zero_row(out_obs, k, i)
        for k in np.flatnonzero(~ended):
            for i in np.flatnonzero(self.padding[k] & ~live[k]):  # padding goes on
                slot_infos[k * self.n_agents + i] = {"padding": True}
                _zero_row(out_obs, k, i)
        for k in np.flatnonzero(ended):
            for i in np.flatnonzero(self.padding[k]):  # the padding segment ends
                done[k, i] = True
                slot_infos[k * self.n_agents + i] = {
                    "padding": True, "terminal_observation": _zero_like_row(obs),
                    "TimeLimit.truncated": False}
            self.padding[k] = False
            self.ep_return[k] = 0.0
            self.ep_length[k] = 0
        reward = np.where(live, rewards, 0.0).astype(np.float32).reshape(-1)
        return self._flat(out_obs), reward, done.reshape(-1), slot_infos

    def close(self) -> None:
        """Close the worlds."""
        self.venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """``getattr`` of the world of each slot in ``indices``."""
        return [getattr(self.venv.envs[j // self.n_agents], attr_name)
                for j in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """``setattr`` on the world of each slot in ``indices``."""
        for j in self._get_indices(indices):
            setattr(self.venv.envs[j // self.n_agents], attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        """A method of the world of each slot in ``indices``."""
        return [getattr(self.venv.envs[j // self.n_agents], method_name)(*method_args,
                                                                          **method_kwargs)
                for j in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """No slot is wrapped."""
        return [False for _ in self._get_indices(indices)]


def _row(obs: Any, k: int, i: int) -> Any:
    if isinstance(obs, dict):
        return {key: v[k, i].copy() for key, v in obs.items()}
    return obs[k, i].copy()


def _copy(obs: Any) -> Any:
    return {key: v.copy() for key, v in obs.items()} if isinstance(obs, dict) else obs.copy()


def _zero_row(obs: Any, k: int, i: int) -> None:
    if isinstance(obs, dict):
        for v in obs.values():
            v[k, i] = 0
    else:
        obs[k, i] = 0


def _zero_like_row(obs: Any) -> Any:
    if isinstance(obs, dict):
        return {key: np.zeros(v.shape[2:], dtype=v.dtype) for key, v in obs.items()}
    return np.zeros(obs.shape[2:], dtype=obs.dtype)
