"""``circuit``: Howard et al.'s loop, one robot driven past six stationary ones.

:class:`CircuitPolicy` keeps every robot but the driver still and drives the
driver around the ``circuit`` world's loop, back past the first robot. The driver
is steered by its true pose (a stand-in for the paper's human driver); the
estimator never sees it.
"""

from __future__ import annotations

import numpy as np

from coop_loc_env.scenarios.howard import CIRCUIT_LOOP, DRIVER
from estimators.geometry import wrap_angle


class CircuitPolicy:
    """Robots other than ``driver`` stand still; the driver follows ``waypoints``.

    The driver heads for each waypoint in turn (true pose: a stand-in for a
    human driver), slowing down in the turns, and stops after the last one.
    """

    name = "circuit"

    def __init__(
        self, waypoints: np.ndarray | None = None, driver: int = DRIVER, reach_m: float = 0.4
    ) -> None:
        self.waypoints = np.asarray(circuit_waypoints() if waypoints is None else waypoints,
                                    dtype=float)
        if self.waypoints.ndim != 2 or self.waypoints.shape[1] != 2:
            raise ValueError(f"waypoints must be (k, 2), got shape {self.waypoints.shape}")
        self.driver = int(driver)
        self.reach_m = float(reach_m)
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset) and start at the first waypoint."""
        if not 0 <= self.driver < env.config.n_robots:
            raise ValueError(f"driver must be a robot index < {env.config.n_robots}, "
                             f"got {self.driver!r}")
        self.env = env
        self.next = 0

    @property
    def finished(self) -> bool:
        """Whether the driver has passed its last waypoint."""
        return self.next >= len(self.waypoints)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Zero for the stationary robots; pure pursuit of the waypoints for the driver."""
        env = self.env
        out = {a: np.zeros(2, dtype=np.float32) for a in env.agents}
        pose = env.world.poses[self.driver]
        while not self.finished and (
            np.hypot(*(self.waypoints[self.next] - pose[:2])) < self.reach_m
        ):
            self.next += 1
        agent = env.possible_agents[self.driver]
        if self.finished or agent not in out:
            return out
        dx, dy = self.waypoints[self.next] - pose[:2]
        err = wrap_angle(np.arctan2(dy, dx) - pose[2])
        speed = np.clip(np.cos(err), 0.0, 1.0) ** 4
        out[agent] = np.array([speed, np.clip(2.0 * err, -1.0, 1.0)], dtype=np.float32)
        return out


def circuit_waypoints(overshoot_m: float = 5.5) -> np.ndarray:
    """The loop's corners counter-clockwise, back to the start corner, then ``overshoot_m``
    along the first leg again (past robot 0, to re-sight it)."""
    loop = np.asarray(CIRCUIT_LOOP, dtype=float)
    first = loop[1] - loop[0]
    end = loop[0] + overshoot_m * first / np.linalg.norm(first)
    return np.vstack([loop[1:], loop[:1], end[None]])
