"""``gather``: drive toward the communicated estimates of the teammates that can inform you."""

from __future__ import annotations

import numpy as np

from policies.scripted.common import Steering, gps_flags
from policies.scripted.view import ViewBuilder


class GatherPolicy:
    """Each robot drives toward the nearest teammate (by the shared estimates) that can
    inform it: a GPS-equipped one for a robot without GPS, one without GPS for a robot
    with it (so the two meet half way); any teammate when the team is homogeneous.

    A robot stands still within ``meet_fraction`` of the detector range of its target
    (where detections bring relative updates) and turns away from obstacles ahead.
    Reads only the team's beliefs, its own laser bins and the robots' hardware.

    Args:
        meet_fraction: stop within this fraction of the detector range, in (0, 1].
        speed: normalized driving speed, in (0, 1].
    """

    name = "gather"

    def __init__(self, meet_fraction: float = 0.5, speed: float = 1.0) -> None:
        if not 0 < meet_fraction <= 1:
            raise ValueError(f"meet_fraction must be in (0, 1], got {meet_fraction!r}")
        if not 0 < speed <= 1:
            raise ValueError(f"speed must be in (0, 1], got {speed!r}")
        self.meet_fraction = float(meet_fraction)
        self.speed = float(speed)
        self.env = None
        self._views: ViewBuilder | None = None
        self._gps = np.zeros(0, dtype=bool)

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env``."""
        self.env = env
        self._views = ViewBuilder(env)
        self._gps = gps_flags(env)
        self._steer = Steering(env.config.n_robots)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent."""
        env = self.env
        stop = self.meet_fraction * env.config.detector_range
        live = np.array([env.agent_name_mapping[a] for a in env.agents])
        est = env.estimated_poses
        actions = {}
        for agent in env.agents:
            view = self._views.view(agent, obs[agent])
            i = view.index
            others = live[live != i]
            useful = others[self._gps[others] != self._gps[i]]
            pool = useful if len(useful) else others
            if not len(pool):
                actions[agent] = np.zeros(2, dtype=np.float32)
                continue
            d = np.hypot(*(est[pool, :2] - est[i, :2]).T)
            target = est[pool[int(np.argmin(d))], :2]
            actions[agent] = self._steer.to(view, target, stop, self.speed)
        return actions
