"""The stable-baselines3 ``VecEnv`` over ParallelEnv copies (see :mod:`policies.learning.vec_env`).

Importing this module imports stable-baselines3 (the ``train`` extra).
"""

from __future__ import annotations

import multiprocessing as mp
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from policies.learning.env_copies import EnvCopies, EnvFn, RemoteCopies, obs_concat


class ParallelEnvVecEnv(VecEnv):
    """SB3 ``VecEnv`` with one slot per agent of ``n_envs`` ParallelEnv copies.

    Args:
        env_fn: a picklable zero-argument factory of the ParallelEnv (see
            :func:`make_env_fn`); all copies must have the same agents and spaces.
        n_envs: number of env copies (``num_envs = n_envs * n_agents``).
        n_procs: ``1`` steps all copies in this process; ``> 1`` runs them in
            that many worker processes (at most ``n_envs``).
        start_method: multiprocessing start method for the workers
            (default ``"forkserver"`` where available, else ``"spawn"``).

    See :mod:`policies.learning.vec_env` for the done/truncation/padding conventions.
    """

    def __init__(
        self, env_fn: EnvFn, n_envs: int = 1, n_procs: int = 1, start_method: str | None = None
    ) -> None:
        if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
            raise ValueError(f"n_envs must be a positive integer, got {n_envs!r}")
        if isinstance(n_procs, bool) or not isinstance(n_procs, int) or n_procs < 1:
            raise ValueError(f"n_procs must be a positive integer, got {n_procs!r}")
        if n_procs > n_envs:
            raise ValueError(f"n_procs must be <= n_envs ({n_envs}), got {n_procs!r}")
        self.n_envs = n_envs
        self.n_procs = n_procs
        blocks = np.array_split(np.arange(n_envs), n_procs)
        self.copy_block = np.concatenate([np.full(len(b), j) for j, b in enumerate(blocks)])
        self.copy_local = np.concatenate([np.arange(len(b)) for b in blocks])
        self.groups: list[Any] = []
        if n_procs == 1:
            local = EnvCopies(env_fn, n_envs)
            self.groups = [local]
            obs_space, act_space, n_agents = (
                local.observation_space, local.action_space, local.n_agents
            )
        else:
            if start_method is None:
                methods = mp.get_all_start_methods()
                start_method = "forkserver" if "forkserver" in methods else "spawn"
            ctx = mp.get_context(start_method)
            try:
                for b in blocks:
                    self.groups.append(RemoteCopies(env_fn, len(b), ctx))
            except Exception:
                for g in self.groups:
                    g.close()
                raise
            g = self.groups[0]
            obs_space, act_space, n_agents = g.observation_space, g.action_space, g.n_agents
        dict_of_boxes = isinstance(obs_space, spaces.Dict) and all(
            isinstance(s, spaces.Box) for s in obs_space.spaces.values())
        if not (isinstance(obs_space, spaces.Box) or dict_of_boxes) or \
                not isinstance(act_space, spaces.Box):
            raise ValueError(
                f"ParallelEnvVecEnv needs Box spaces (or a Dict of Box observations), got "
                f"{obs_space!r} and {act_space!r}"
            )
        self.n_agents = n_agents
        self._actions: np.ndarray | None = None
        self._closed = False
        super().__init__(n_envs * n_agents, obs_space, act_space)

    # ------------------------------------------------------------------ helpers
    def _remote(self) -> bool:
        return self.n_procs > 1

    def _slot_copies(self, indices: VecEnvIndices) -> list[int]:
        """Copy index of each requested slot."""
        return [i // self.n_agents for i in self._get_indices(indices)]

    def _per_group(self, copies: list[int]) -> dict[int, list[int]]:
        out: dict[int, list[int]] = {}
        for k in copies:
            out.setdefault(int(self.copy_block[k]), []).append(int(self.copy_local[k]))
        return out

    def _call_groups(self, cmd: str, per_group: dict[int, Any]) -> dict[int, Any]:
        """Run ``cmd`` with per-group argument tuples on the groups (in parallel when remote)."""
        if not self._remote():
            return {0: getattr(self.groups[0], cmd)(*per_group[0])}
        for j, data in per_group.items():
            self.groups[j].send(cmd, data)
        return {j: self.groups[j].receive() for j in per_group}

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> np.ndarray:
        """Reset every copy, seeding copy ``k`` with the seed of its first slot."""
        seeds = [self._seeds[k * self.n_agents] for k in range(self.n_envs)]
        per_group = {
            j: ([seeds[k] for k in range(self.n_envs) if self.copy_block[k] == j],)
            for j in range(len(self.groups))
        }
        results = self._call_groups("reset", per_group)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return obs_concat([results[j] for j in range(len(self.groups))])

    def step_async(self, actions: np.ndarray) -> None:
        """Send the actions ``(num_envs, act)`` to the copies."""
        actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, -1)
        if not self._remote():
            self._actions = actions
            return
        start = 0
        for g in self.groups:
            stop = start + g.n_copies * self.n_agents
            g.send("step", (actions[start:stop],))
            start = stop

    def step_wait(self) -> VecEnvStepReturn:
        """Observations, rewards, dones and infos of every slot."""
        if not self._remote():
            if self._actions is None:
                raise ValueError("step_wait() called before step_async()")
            result = self.groups[0].step(self._actions)
            self._actions = None
            return result
        parts = [g.receive() for g in self.groups]
        obs = obs_concat([p[0] for p in parts])
        rew = np.concatenate([p[1] for p in parts])
        done = np.concatenate([p[2] for p in parts])
        infos = [info for p in parts for info in p[3]]
        return obs, rew, done, infos

    def close(self) -> None:
        """Close the copies and stop the workers."""
        if self._closed:
            return
        for g in self.groups:
            g.close()
        self._closed = True

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """``getattr`` on the env copy of each requested slot."""
        copies = self._slot_copies(indices)
        per_group = self._per_group(sorted(set(copies)))
        results = self._call_groups(
            "get_attr", {j: (attr_name, ks) for j, ks in per_group.items()}
        )
        value = {}
        for j, ks in per_group.items():
            for local, v in zip(ks, results[j], strict=True):
                value[(j, local)] = v
        return [value[(int(self.copy_block[k]), int(self.copy_local[k]))] for k in copies]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """``setattr`` on the env copy of each requested slot."""
        per_group = self._per_group(sorted(set(self._slot_copies(indices))))
        self._call_groups("set_attr", {j: (attr_name, value, ks) for j, ks in per_group.items()})

    def env_method(
        self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs
    ) -> list[Any]:
        """Call a method of the env copy of each requested slot (once per copy)."""
        copies = self._slot_copies(indices)
        per_group = self._per_group(sorted(set(copies)))
        results = self._call_groups(
            "env_method",
            {j: (method_name, method_args, method_kwargs, ks) for j, ks in per_group.items()},
        )
        value = {}
        for j, ks in per_group.items():
            for local, v in zip(ks, results[j], strict=True):
                value[(j, local)] = v
        return [value[(int(self.copy_block[k]), int(self.copy_local[k]))] for k in copies]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """ParallelEnv copies are never gymnasium-wrapped: all ``False``."""
        return [False for _ in self._get_indices(indices)]
