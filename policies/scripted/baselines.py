"""Baseline policies and the interface every policy in this package follows.

A policy is bound to an env at :meth:`Policy.reset` (called right after the
env's own reset) and maps the observations of the live agents to actions.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from estimators.geometry import wrap_angle
from policies.scripted.view import RobotView, ViewBuilder


class Policy(Protocol):
    """What :func:`policies.episode.run_episode` needs from a policy."""

    name: str

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset) for a new episode."""
        ...

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent of the bound env."""
        ...


class RandomPolicy:
    """Uniform random actions in ``[-1, 1]^2`` (seeded per episode)."""

    name = "random"

    def __init__(self) -> None:
        self.env = None
        self.rng = np.random.default_rng(0)

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` and reseed."""
        self.env = env
        self.rng = np.random.default_rng(seed)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """A uniform action per live agent."""
        return {
            a: self.rng.uniform(-1.0, 1.0, size=2).astype(np.float32) for a in self.env.agents
        }


class StandStillPolicy:
    """Every robot stands still (zero action): the reference for how low the error gets
    without moving."""

    name = "still"

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env``."""
        self.env = env

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """A zero action per live agent."""
        return {a: np.zeros(2, dtype=np.float32) for a in self.env.agents}


def wander(view: RobotView, rng: np.random.Generator, speed: float = 0.6) -> np.ndarray:
    """Drive forward, turning toward the freer side when the front is blocked."""
    front = view.min_range(-0.7, 0.7)
    if front < 1.5:
        left, right = view.min_range(0.7, 1.6), view.min_range(-1.6, -0.7)
        return np.array([0.0, 0.8 if left >= right else -0.8], dtype=np.float32)
    return np.array([speed, rng.normal(0.0, 0.3)], dtype=np.float32).clip(-1, 1)


class SeekTeammatePolicy:
    """Wander; when uncertain, drive toward the nearest teammate's shared estimate.

    A robot whose RMS position standard deviation exceeds ``std_threshold``
    heads for the nearest teammate (by the estimates the team shares) until it
    is within ``meet_fraction`` of the detector range, where a detection can
    trigger a cooperative update; otherwise it wanders, avoiding obstacles.

    Args:
        std_threshold: position std (m) above which the robot seeks a teammate.
        meet_fraction: stop approaching within this fraction of the detector range.
    """

    name = "seek"

    def __init__(self, std_threshold: float = 0.8, meet_fraction: float = 0.5) -> None:
        if not std_threshold > 0:
            raise ValueError(f"std_threshold must be > 0, got {std_threshold!r}")
        if not 0 < meet_fraction <= 1:
            raise ValueError(f"meet_fraction must be in (0, 1], got {meet_fraction!r}")
        self.std_threshold = float(std_threshold)
        self.meet_fraction = float(meet_fraction)
        self.env = None
        self._views: ViewBuilder | None = None
        self.rng = np.random.default_rng(0)
        self.seeking: dict[str, bool] = {}

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` and reseed."""
        self.env = env
        self._views = ViewBuilder(env)
        self.rng = np.random.default_rng(seed)
        self.seeking = {a: False for a in env.possible_agents}

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Seek or wander, per live agent."""
        meet = self.meet_fraction * self.env.config.detector_range
        live = [self.env.agent_name_mapping[a] for a in self.env.agents]
        actions = {}
        for agent in self.env.agents:
            view = self._views.view(agent, obs[agent])
            others = [j for j in live if j != view.index]
            seek = bool(others) and view.position_std > self.std_threshold
            self.seeking[agent] = seek
            if not seek:
                actions[agent] = wander(view, self.rng)
                continue
            d = view.teammates[others, :2] - view.est_pose[:2]
            dist = np.hypot(d[:, 0], d[:, 1])
            k = int(np.argmin(dist))
            err = float(wrap_angle(np.arctan2(d[k, 1], d[k, 0]) - view.est_pose[2]))
            if dist[k] < meet:
                actions[agent] = np.array([0.0, np.clip(1.5 * err, -1, 1)], dtype=np.float32)
            elif view.min_range(-0.7, 0.7) < 1.2:
                actions[agent] = wander(view, self.rng)
            else:
                v = 0.7 * max(0.0, np.cos(err)) ** 2
                actions[agent] = np.array([v, np.clip(1.5 * err, -1, 1)], dtype=np.float32)
        return actions
