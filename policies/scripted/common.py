"""Helpers shared by the scripted baselines: steering to a point, who carries GPS."""

from __future__ import annotations

import numpy as np

from estimators.geometry import wrap_angle
from policies.scripted.view import RobotView

FRONT = 0.7  # half-width (rad) of the sector checked for obstacles ahead
BLOCKED = 1.2  # an obstacle nearer than this (m) ahead makes the robot turn away


def gps_flags(env) -> np.ndarray:
    """``(n,)`` whether each robot carries a GPS receiver (hardware, known to the team)."""
    return np.array([env.config.robot_spec(i).has_gps for i in range(env.config.n_robots)])


def avoid(view: RobotView) -> np.ndarray | None:
    """A turn-in-place action away from an obstacle just ahead, or ``None`` if the way is free."""
    if view.min_range(-FRONT, FRONT) >= BLOCKED:
        return None
    left, right = view.min_range(FRONT, 1.6), view.min_range(-1.6, -FRONT)
    return np.array([0.0, 0.8 if left >= right else -0.8], dtype=np.float32)


class Steering:
    """Heading and point tracking by the robots' own estimates, with obstacle detours.

    When the laser sees an obstacle ahead on the way, the robot takes a detour for
    ``DETOUR_STEPS`` steps: it heads 90 degrees off its goal heading, to the freer side.
    """

    DETOUR_STEPS = 15

    def __init__(self, n: int) -> None:
        self.detour = np.zeros(n, dtype=int)
        self.detour_heading = np.zeros(n)

    def heading(self, view: RobotView, heading: float, speed: float = 1.0) -> np.ndarray:
        """Drive along world ``heading`` (rad) by the robot's estimate."""
        i = view.index
        err = float(wrap_angle(heading - view.est_pose[2]))
        if self.detour[i] == 0 and abs(err) < 1.2 and avoid(view) is not None:
            left, right = view.min_range(FRONT, 1.6), view.min_range(-1.6, -FRONT)
            side = 1.0 if left >= right else -1.0
            self.detour[i] = self.DETOUR_STEPS
            self.detour_heading[i] = view.est_pose[2] + side * np.pi / 2
        if self.detour[i] > 0:
            self.detour[i] -= 1
            err = float(wrap_angle(self.detour_heading[i] - view.est_pose[2]))
            if abs(err) < 1.2 and view.min_range(-FRONT, FRONT) < 0.5 * BLOCKED:
                return np.array([0.0, 0.8 if err >= 0 else -0.8], dtype=np.float32)
        turn = float(np.clip(2.0 * err, -1.0, 1.0))
        v = speed * max(0.0, np.cos(err)) ** 2
        return np.array([v, turn], dtype=np.float32)

    def to(self, view: RobotView, target: np.ndarray, stop: float, speed: float = 1.0
           ) -> np.ndarray:
        """Drive toward world point ``target`` by the robot's estimate; stand within ``stop`` m."""
        d = np.asarray(target, dtype=float) - view.est_pose[:2]
        if float(np.hypot(d[0], d[1])) < stop:
            self.detour[view.index] = 0
            return np.zeros(2, dtype=np.float32)
        return self.heading(view, float(np.arctan2(d[1], d[0])), speed)
