"""A stable-baselines3 ``VecEnv`` over copies of a PettingZoo ``ParallelEnv`` (parameter sharing).

The ``VecEnv`` class, :class:`~policies.learning.sb3_vec_env.ParallelEnvVecEnv`, lives in
:mod:`policies.learning.sb3_vec_env` (importing it imports stable-baselines3; it is also
reachable here as ``policies.learning.vec_env.ParallelEnvVecEnv``); this module holds the
env factory and the reward wrapper, :mod:`policies.learning.env_copies` the env copies and
the workers, which need no stable-baselines3.

Every agent of every env copy is one slot of the ``VecEnv``: with ``n_envs``
copies of an env with ``n`` agents, ``num_envs = n_envs * n`` and slot
``k * n + i`` is agent ``possible_agents[i]`` of copy ``k``. One policy then
acts for all agents (they are interchangeable; the observation holds the
agent's own features, never its index).

Episode ends are reported the way SB3 expects (unlike SuperSuit's
``pettingzoo_env_to_vec_env_v1``, which merges terminated and truncated):

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

from functools import partial
from typing import Any

import numpy as np

import coop_loc_env
from policies.learning.env_copies import EnvFn

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
    ``threshold`` (1.5 m, the metric of :mod:`policies.experiments.compare`). Its reward per step:

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


def __getattr__(name: str) -> Any:
    """``ParallelEnvVecEnv`` from :mod:`policies.learning.sb3_vec_env` (stable-baselines3 on
    demand)."""
    if name == "ParallelEnvVecEnv":
        from policies.learning.sb3_vec_env import ParallelEnvVecEnv

        return ParallelEnvVecEnv
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
