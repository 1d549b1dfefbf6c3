"""ParallelEnv copies stepped in this process or in worker processes (no stable-baselines3).

:class:`EnvCopies` steps ``n_copies`` copies of a PettingZoo ``ParallelEnv``
with one slot per agent of every copy, following the done, truncation and
padding conventions of :mod:`policies.learning.vec_env`; :class:`RemoteCopies`
runs one in a pipe-based worker process (like SB3's ``SubprocVecEnv``). The
``obs_*`` helpers stack observations that are arrays or dicts of arrays.
:class:`~policies.learning.sb3_vec_env.ParallelEnvVecEnv` is built on them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import cloudpickle
import numpy as np
from gymnasium import spaces

EnvFn = Callable[[], Any]
_COMMANDS = ("step", "reset", "get_attr", "set_attr", "env_method")


def obs_zeros(space: spaces.Space, n: int | None = None) -> np.ndarray | dict[str, np.ndarray]:
    """Zero observation(s) of ``space`` (a ``Box`` or a ``Dict`` of boxes), ``n`` stacked."""
    if isinstance(space, spaces.Dict):
        return {k: obs_zeros(s, n) for k, s in space.spaces.items()}
    lead = () if n is None else (n,)
    return np.zeros(lead + space.shape, dtype=space.dtype)


def obs_stack(items: list) -> np.ndarray | dict[str, np.ndarray]:
    """Observations (arrays or dicts of arrays) stacked along a new first axis."""
    if isinstance(items[0], dict):
        return {k: np.stack([x[k] for x in items]) for k in items[0]}
    return np.stack(items)


def obs_concat(parts: list) -> np.ndarray | dict[str, np.ndarray]:
    """Stacked observations concatenated along the first axis."""
    if isinstance(parts[0], dict):
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return np.concatenate(parts)


def obs_set(stacked: np.ndarray | dict, i: int, value: np.ndarray | dict) -> None:
    """Row ``i`` of stacked observations set to ``value``."""
    if isinstance(stacked, dict):
        for k, v in stacked.items():
            v[i] = value[k]
    else:
        stacked[i] = value


class EnvCopies:
    """``n_copies`` ParallelEnv copies stepped in one process; the unit a worker runs.

    Arrays are slot-major: row ``k * n_agents + i`` is agent ``i`` of copy ``k``.
    """

    def __init__(self, env_fn: EnvFn, n_copies: int) -> None:
        if isinstance(n_copies, bool) or not isinstance(n_copies, int) or n_copies < 1:
            raise ValueError(f"n_copies must be a positive integer, got {n_copies!r}")
        self.envs = [env_fn() for _ in range(n_copies)]
        first = self.envs[0]
        self.agents = list(first.possible_agents)
        self.n_agents = len(self.agents)
        self.observation_space = first.observation_space(self.agents[0])
        self.action_space = first.action_space(self.agents[0])
        shape = (n_copies, self.n_agents)
        self.padding = np.zeros(shape, dtype=bool)  # agent done, copy not yet reset
        self.ep_return = np.zeros(shape)
        self.ep_length = np.zeros(shape, dtype=np.int64)
        self.start_time = time.time()

    @property
    def n_slots(self) -> int:
        """``n_copies * n_agents``."""
        return len(self.envs) * self.n_agents

    def _zeros(self) -> np.ndarray | dict[str, np.ndarray]:
        return obs_zeros(self.observation_space)

    def _reset_copy(self, k: int, seed: int | None) -> np.ndarray:
        obs, _ = self.envs[k].reset(seed=seed)
        self.padding[k] = False
        self.ep_return[k] = 0.0
        self.ep_length[k] = 0
        return obs_stack([obs[a] for a in self.agents])

    def reset(self, seeds: Sequence[int | None]) -> np.ndarray:
        """Reset every copy (copy ``k`` with ``seeds[k]``); observations ``(n_slots, obs)``."""
        if len(seeds) != len(self.envs):
            raise ValueError(f"need one seed per copy ({len(self.envs)}), got {list(seeds)!r}")
        return obs_concat([self._reset_copy(k, s) for k, s in enumerate(seeds)])

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        """Step every copy with ``actions (n_slots, act)``; auto-resets finished copies."""
        actions = np.asarray(actions, dtype=np.float32).reshape(self.n_slots, -1)
        low, high = self.action_space.low, self.action_space.high
        obs_out, rew_out, done_out, info_out = [], [], [], []
        for k, env in enumerate(self.envs):
            rows = slice(k * self.n_agents, (k + 1) * self.n_agents)
            act = np.clip(actions[rows], low, high)
            live = list(env.agents)
            obs, rewards, terms, truncs, infos = env.step(
                {a: act[self.agent_index(a)] for a in live}
            )
            o = obs_zeros(self.observation_space, self.n_agents)
            r = np.zeros(self.n_agents, dtype=np.float32)
            d = np.zeros(self.n_agents, dtype=bool)
            slot_infos: list[dict] = [{} for _ in range(self.n_agents)]
            was_padding = self.padding[k].copy()
            for i, agent in enumerate(self.agents):
                if agent not in rewards:  # padding slot: zeros, reward 0, action ignored
                    slot_infos[i] = {"padding": True}
                    continue
                r[i] = rewards[agent]
                self.ep_return[k, i] += rewards[agent]
                self.ep_length[k, i] += 1
                info = dict(infos[agent])
                if terms[agent] or truncs[agent]:
                    d[i] = True
                    info["terminal_observation"] = obs[agent]
                    info["TimeLimit.truncated"] = bool(truncs[agent] and not terms[agent])
                    info["episode"] = {
                        "r": float(self.ep_return[k, i]),
                        "l": int(self.ep_length[k, i]),
                        "t": round(time.time() - self.start_time, 6),
                    }
                    self.padding[k, i] = True
                else:
                    obs_set(o, i, obs[agent])
                slot_infos[i] = info
            if not env.agents:
                o = self._reset_copy(k, None)
                for i in np.flatnonzero(was_padding):
                    d[i] = True
                    slot_infos[i] = {
                        "padding": True,
                        "terminal_observation": self._zeros(),
                        "TimeLimit.truncated": False,
                    }
            obs_out.append(o)
            rew_out.append(r)
            done_out.append(d)
            info_out.extend(slot_infos)
        return obs_concat(obs_out), np.concatenate(rew_out), np.concatenate(done_out), info_out

    def agent_index(self, agent: str) -> int:
        """Index of ``agent`` in ``possible_agents``."""
        return self.agents.index(agent)

    def get_attr(self, name: str, copies: Sequence[int]) -> list[Any]:
        """``getattr(env, name)`` of the given copies."""
        return [getattr(self.envs[k], name) for k in copies]

    def set_attr(self, name: str, value: Any, copies: Sequence[int]) -> None:
        """``setattr(env, name, value)`` on the given copies."""
        for k in copies:
            setattr(self.envs[k], name, value)

    def env_method(self, name: str, args: tuple, kwargs: dict, copies: Sequence[int]) -> list:
        """``env.name(*args, **kwargs)`` on the given copies."""
        return [getattr(self.envs[k], name)(*args, **kwargs) for k in copies]

    def close(self) -> None:
        """Close every copy."""
        for env in self.envs:
            env.close()


def _worker(remote, parent_remote, payload: bytes) -> None:
    """Worker process: builds an :class:`EnvCopies` and serves commands over a pipe."""
    parent_remote.close()
    env_fn, n_copies = cloudpickle.loads(payload)
    copies = None
    try:
        copies = EnvCopies(env_fn, n_copies)
        remote.send(("ok", (copies.observation_space, copies.action_space, copies.n_agents)))
        while True:
            cmd, data = remote.recv()
            if cmd == "close":
                break
            try:
                if cmd not in _COMMANDS:
                    raise ValueError(f"unknown worker command {cmd!r}")
                result = getattr(copies, cmd)(*data)
                remote.send(("ok", result))
            except Exception as err:  # report to the parent, keep serving
                remote.send(("error", err))
    except (KeyboardInterrupt, EOFError):
        pass
    except Exception as err:  # construction failed
        remote.send(("error", err))
    finally:
        if copies is not None:
            copies.close()
        remote.close()


class RemoteCopies:
    """The parent's handle on a worker process running an :class:`EnvCopies`."""

    def __init__(self, env_fn: EnvFn, n_copies: int, ctx) -> None:
        self.remote, work_remote = ctx.Pipe()
        payload = cloudpickle.dumps((env_fn, n_copies))
        self.process = ctx.Process(
            target=_worker, args=(work_remote, self.remote, payload), daemon=True
        )
        self.process.start()
        work_remote.close()
        self.observation_space, self.action_space, self.n_agents = self.receive()
        self.n_copies = n_copies

    def send(self, cmd: str, data: Any = None) -> None:
        self.remote.send((cmd, data))

    def receive(self) -> Any:
        status, result = self.remote.recv()
        if status == "error":
            raise result
        return result

    def call(self, cmd: str, data: Any = None) -> Any:
        self.send(cmd, data)
        return self.receive()

    def close(self) -> None:
        try:
            self.send("close")
        except (BrokenPipeError, OSError):
            pass
        self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.terminate()
