"""Screening of map landmarks whose readings are off the same way for several robots.

A landmark that the map puts in the wrong place (a survey error, a moved
landmark) pulls every robot that reads it; the gate lets its readings in as
long as the error is within the noise model's generous bounds. One robot's
readings alone cannot tell a wrong landmark from a wrong robot, but the same
world-frame offset seen by two robots, each from its own belief, can: a
robot's own error does not repeat in another robot's readings.

:class:`LandmarkScreen` keeps, per landmark and robot, the readings of the last
``window_s`` seconds as the landmark position each implies (the robot's belief
plus the reading), its offset from the map and that offset's covariance (the
belief's and the reading's). A landmark is flagged when the mean offsets of
``min_robots`` robots, each from ``min_readings`` readings or more, are each at
least ``min_offset_m`` long and agree with each other (chi-square test at
``prob`` of their differences, with each mean's covariance taken as the mean
covariance over the square root of the readings' count: a camera's errors on
one landmark persist over seconds, so its readings do not average as
independent ones). Its readings then count the agreed offset as map
uncertainty (:meth:`LandmarkScreen.inflate`), which widens them most across
the line of sight, where a misplaced landmark shows in the bearing.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from estimators.gating import chi2_threshold

__all__ = ["LandmarkScreen"]


class _Track:
    """One robot's recent readings of one landmark, with running sums."""

    def __init__(self) -> None:
        self.readings: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self.sum_offset = np.zeros(2)
        self.sum_cov = np.zeros((2, 2))

    def add(self, time: float, offset: np.ndarray, cov: np.ndarray) -> None:
        self.readings.append((time, offset, cov))
        self.sum_offset = self.sum_offset + offset
        self.sum_cov = self.sum_cov + cov

    def forget(self, before: float) -> None:
        while self.readings and self.readings[0][0] < before:
            _, offset, cov = self.readings.popleft()
            self.sum_offset = self.sum_offset - offset
            self.sum_cov = self.sum_cov - cov


class LandmarkScreen:
    """Per-landmark, per-robot offsets of the implied landmark positions from the map.

    Args:
        window_s: readings older than this (s) are forgotten.
        min_robots: robots whose mean offsets must agree, at least (>= 2).
        min_offset_m: the shortest mean offset that flags a landmark (m).
        prob: probability of the chi-square test that two robots' offsets agree.
        min_readings: readings a robot needs in the window for its mean to count.
    """

    def __init__(
        self, window_s: float = 30.0, min_robots: int = 2, min_offset_m: float = 0.2,
        prob: float = 0.9, min_readings: int = 5,
    ) -> None:
        if not (np.isfinite(window_s) and window_s > 0):
            raise ValueError(f"window_s must be finite and > 0, got {window_s!r}")
        if isinstance(min_robots, bool) or not isinstance(min_robots, int) or min_robots < 2:
            raise ValueError(f"min_robots must be an int >= 2, got {min_robots!r}")
        if not (np.isfinite(min_offset_m) and min_offset_m >= 0):
            raise ValueError(f"min_offset_m must be finite and >= 0, got {min_offset_m!r}")
        if isinstance(min_readings, bool) or not isinstance(min_readings, int) \
                or min_readings < 1:
            raise ValueError(f"min_readings must be a positive int, got {min_readings!r}")
        self.window_s = float(window_s)
        self.min_robots = min_robots
        self.min_offset_m = float(min_offset_m)
        self.bound = chi2_threshold(prob, 2)
        self.min_readings = min_readings
        # landmark -> robot -> (readings (time, offset, cov), running sums of offset, cov)
        self._kept: dict[int, dict[int, _Track]] = {}
        self.flags = 0  # readings whose noise was inflated

    def add(
        self, landmark: int, robot: int, time: float, mean: np.ndarray, cov: np.ndarray,
        sensor: np.ndarray, mark: np.ndarray, z: np.ndarray, r: np.ndarray,
    ) -> None:
        """Keep robot ``robot``'s reading ``z`` (range, bearing; noise ``r``) of ``landmark``
        at map position ``mark``, taken at ``time`` from the belief ``mean (3,)``, ``cov
        (3, 3)``, with the sensor at ``sensor (2,)`` in the body frame."""
        c, s = np.cos(mean[2]), np.sin(mean[2])
        arm = np.array([c * sensor[0] - s * sensor[1], s * sensor[0] + c * sensor[1]])
        ray = mean[2] + z[1]
        u = np.array([np.cos(ray), np.sin(ray)])
        perp = np.array([-u[1], u[0]])
        implied = mean[:2] + arm + z[0] * u
        j_pose = np.array([[1.0, 0.0, -arm[1] - z[0] * u[1]], [0.0, 1.0, arm[0] + z[0] * u[0]]])
        j_z = np.column_stack([u, z[0] * perp])
        cov_off = j_pose @ cov @ j_pose.T + j_z @ r @ j_z.T
        track = self._kept.setdefault(landmark, {}).setdefault(robot, _Track())
        track.add(float(time), implied - np.asarray(mark, dtype=float), cov_off)
        track.forget(time - self.window_s)

    def offset(self, landmark: int, time: float) -> np.ndarray | None:
        """The agreed world-frame offset ``(2,)`` of ``landmark`` from the map at ``time``,
        or ``None`` when it is not flagged."""
        means = []
        for track in self._kept.get(landmark, {}).values():
            track.forget(time - self.window_s)
            n = len(track.readings)
            if n < self.min_readings:
                continue
            e = track.sum_offset / n
            if float(np.hypot(*e)) >= self.min_offset_m:
                means.append((e, track.sum_cov / (n * np.sqrt(n))))
        if len(means) < self.min_robots:
            return None
        for a in range(len(means)):
            for b in range(a + 1, len(means)):
                d = means[a][0] - means[b][0]
                if d @ np.linalg.solve(means[a][1] + means[b][1], d) > self.bound:
                    return None
        return np.mean([m[0] for m in means], axis=0)

    def inflate(
        self, landmark: int, time: float, mean: np.ndarray, sensor: np.ndarray,
        mark: np.ndarray, r: np.ndarray,
    ) -> np.ndarray:
        """The reading noise ``r (2, 2)`` of a reading of ``landmark`` from the belief
        ``mean``, with the landmark's agreed offset added as map uncertainty (``r`` itself
        when it is not flagged)."""
        off = self.offset(landmark, time)
        if off is None:
            return r
        c, s = np.cos(mean[2]), np.sin(mean[2])
        pos = mean[:2] + np.array([c * sensor[0] - s * sensor[1], s * sensor[0] + c * sensor[1]])
        d = np.asarray(mark, dtype=float) - pos
        q = float(d @ d)
        if q < 1e-12:
            return r
        h = np.array([[d[0], d[1]] / np.sqrt(q), [-d[1] / q, d[0] / q]])
        self.flags += 1
        return r + h @ np.outer(off, off) @ h.T
