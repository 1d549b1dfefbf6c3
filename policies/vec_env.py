"""A stable-baselines3 ``VecEnv`` over copies of a PettingZoo ``ParallelEnv`` (parameter sharing).

The ``VecEnv`` class, :class:`~policies.sb3_vec_env.ParallelEnvVecEnv`, lives in
:mod:`policies.sb3_vec_env` (importing it imports stable-baselines3; it is also
reachable here as ``policies.vec_env.ParallelEnvVecEnv``); this module holds the env
copies, the workers and the reward wrappers, which need no stable-baselines3.

Every agent of every env copy is one slot of the ``VecEnv``: with ``n_envs``
copies of an env with ``n`` agents, ``num_envs = n_envs * n`` and slot
``k * n + i`` is agent ``possible_agents[i]`` of copy ``k``. One policy then
acts for all agents (they are interchangeable; the observation holds the
agent's own features, never its index).

Episode ends are reported the way SB3 expects (unlike SuperSuit's
``pettingzoo_env_to_vec_env_v1``, which merges terminated and truncated,
PettingZoo issue #1126):

* when an agent's episode ends, its slot returns ``done=True`` with
  ``info["terminal_observation"]`` (the env's last observation of that agent)
  and ``info["TimeLimit.truncated"] = truncated and not terminated``, so PPO
  bootstraps the value on ``max_cycles`` truncation and not on a tip-over;
  ``info["episode"] = {"r", "l", "t"}`` holds the agent's return and length
  (what SB3 logs as ``rollout/ep_rew_mean``);
* an agent that terminates early (a tip-over removes it from ``env.agents``)
  leaves a *padding* slot until its copy resets: the slot observes zeros, gets
  reward 0 and ``done=False``, and its actions are ignored. When the copy
  resets, the padding slot returns ``done=True`` once more, as a termination
  (``TimeLimit.truncated = False``, ``info["padding"] = True``, zero terminal
  observation), so no value is bootstrapped from the next episode into the
  padding segment;
* a copy resets itself (auto-reset) when none of its agents is left; the
  observation returned for its slots is then the first of the new episode.

Seeding: the first reset of copy ``k`` uses the seed SB3 set for the copy's
first slot (``VecEnv.seed(s)`` gives slot ``j`` seed ``s + j``, so copy ``k``
gets ``s + k * n``); later auto-resets continue the copy's own generator, so a
run is reproducible from its seed.

Processes: with ``n_procs = 1`` every copy runs in this process; with
``n_procs > 1`` the copies are split into ``n_procs`` contiguous blocks, each
stepped by one worker process (a pipe-based worker, like SB3's
``SubprocVecEnv``), all workers stepping in parallel.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import cloudpickle
import numpy as np
from gymnasium import spaces

import coop_loc_env

EnvFn = Callable[[], Any]
_COMMANDS = ("step", "reset", "get_attr", "set_attr", "env_method")


REWARD_MODES = ("env", "localize")


def make_env_fn(
    scenario: str = "outdoor_terrain",
    reward_mode: str = "env",
    reward_kwargs: dict[str, Any] | None = None,
    **overrides: Any,
) -> EnvFn:
    """A picklable factory of ``coop_loc_env.parallel_env(scenario, **overrides)``.

    ``reward_mode="localize"`` wraps the env in :class:`TimeToLocalizeReward`
    (``reward_kwargs`` are its keyword arguments); ``"env"`` keeps the env's rewards.
    """
    if reward_mode not in REWARD_MODES:
        raise ValueError(f"reward_mode must be one of {REWARD_MODES}, got {reward_mode!r}")
    coop_loc_env.make_config(scenario, **overrides)  # fail early, naming the bad key/value
    if reward_mode == "localize":
        TimeToLocalizeReward.check_kwargs(**(reward_kwargs or {}))
        return partial(_localize_env, scenario, dict(reward_kwargs or {}), overrides)
    return partial(coop_loc_env.parallel_env, scenario, **overrides)


def _localize_env(scenario: str, reward_kwargs: dict[str, Any], overrides: dict[str, Any]):
    return TimeToLocalizeReward(coop_loc_env.parallel_env(scenario, **overrides), **reward_kwargs)


class TimeToLocalizeReward:
    """A ParallelEnv wrapper whose per-robot reward is minus the time to localize.

    Robot ``i`` is *localized* from the first step its ``info["particle_spread"]``
    (MCL; the Gaussian ``sqrt(var_x + var_y)`` otherwise) falls below
    ``threshold`` (1.5 m, the metric of :mod:`policies.compare`). Its reward per step:

        ``-step_reward * ((1 - team_weight) * [i not localized]
        + team_weight * (fraction of the team not localized))
        - collision_weight * new contacts``

    so with ``team_weight = 0`` an episode's undiscounted return is
    ``-step_reward`` times the robot's steps to localize (what the evaluation
    measures), and ``team_weight > 0`` also pays a localized robot for its
    teammates (whom it can help through detections). The rewards use the true
    pose (through the spread); the observations are the env's, untouched.
    Everything else is forwarded to the wrapped env.
    """

    def __init__(
        self,
        env,
        step_reward: float = 0.1,
        team_weight: float = 0.0,
        collision_weight: float = 0.0,
        threshold: float = 1.5,
    ) -> None:
        self.check_kwargs(step_reward, team_weight, collision_weight, threshold)
        self.env = env
        self.step_reward = float(step_reward)
        self.team_weight = float(team_weight)
        self.collision_weight = float(collision_weight)
        self.threshold = float(threshold)
        self.localized = np.zeros(len(env.possible_agents), dtype=bool)

    @staticmethod
    def check_kwargs(
        step_reward: float = 0.1,
        team_weight: float = 0.0,
        collision_weight: float = 0.0,
        threshold: float = 1.5,
    ) -> None:
        """Raise ``ValueError`` naming a bad argument."""
        if not step_reward > 0:
            raise ValueError(f"step_reward must be > 0, got {step_reward!r}")
        if not 0 <= team_weight <= 1:
            raise ValueError(f"team_weight must be in [0, 1], got {team_weight!r}")
        if not collision_weight >= 0:
            raise ValueError(f"collision_weight must be >= 0, got {collision_weight!r}")
        if not threshold > 0:
            raise ValueError(f"threshold must be > 0, got {threshold!r}")

    def __getattr__(self, name: str) -> Any:
        if name == "env":  # not yet set (unpickling): avoid recursion
            raise AttributeError(name)
        return getattr(self.env, name)

    @staticmethod
    def spread(info: dict) -> float:
        """The robot's spread (m): ``particle_spread``, else ``sqrt(var_x + var_y)``."""
        spread = float(info.get("particle_spread", np.nan))  # NaN: not an MCL robot
        if np.isfinite(spread):
            return spread
        cov = np.asarray(info["pose_cov"])
        return float(np.sqrt(cov[0, 0] + cov[1, 1]))

    def _update(self, infos: dict[str, dict]) -> None:
        index = self.env.agent_name_mapping
        for agent, info in infos.items():
            if self.spread(info) < self.threshold:
                self.localized[index[agent]] = True

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset the env; no robot counts as localized at the start."""
        obs, infos = self.env.reset(seed=seed, options=options)
        self.localized[:] = False
        return obs, infos

    def step(self, actions: dict[str, Any]):
        """Step the env and replace its rewards."""
        obs, _, terms, truncs, infos = self.env.step(actions)
        self._update(infos)
        index = self.env.agent_name_mapping
        team_lost = float(np.mean(~self.localized))
        rewards = {}
        for agent, info in infos.items():
            lost = float(not self.localized[index[agent]])
            r = -self.step_reward * ((1 - self.team_weight) * lost + self.team_weight * team_lost)
            rewards[agent] = r - self.collision_weight * float(info.get("collisions", 0))
        return obs, rewards, terms, truncs, infos

    def close(self) -> None:
        """Close the wrapped env."""
        self.env.close()


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


class _RemoteCopies:
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


def __getattr__(name: str) -> Any:
    """``ParallelEnvVecEnv`` from :mod:`policies.sb3_vec_env` (stable-baselines3 on demand)."""
    if name == "ParallelEnvVecEnv":
        from policies.sb3_vec_env import ParallelEnvVecEnv

        return ParallelEnvVecEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
