"""``wander``: Fox et al.'s behaviour, forward and away from obstacles by the robot's own scan.

The robots of Fox, Burgard, Kruppa and Thrun's simulations move about without
knowing where they are; :class:`WanderPolicy` reads only each robot's own
range readings (:class:`~policies.scripted.view.ScanView`).
"""

from __future__ import annotations

import numpy as np

from policies.scripted.baselines import wander
from policies.scripted.view import ScanView


class WanderPolicy:
    """Drive forward at ``speed``; turn in place toward the freer side when blocked.

    Uses each robot's own range scan only, beam by beam (``env.last_readings``
    with ``env.sensors.beam_angles``; the observation's range bins min-pool the
    beams of a team's longest scan, which misplaces a sonar's 16 beams in a
    team that also has 30-beam lasers). Seeded per episode.
    """

    name = "wander"

    def __init__(self, speed: float = 0.6) -> None:
        if not 0 < speed <= 1:
            raise ValueError(f"speed must be in (0, 1], got {speed!r}")
        self.speed = float(speed)
        self.env = None
        self.rng = np.random.default_rng(0)

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset) and reseed."""
        self.env = env
        self.rng = np.random.default_rng(seed)
        sensors = env.sensors
        self._angles = [np.asarray(a, dtype=float) for a in sensors.beam_angles]
        self._rmax = np.asarray(sensors.range_max, dtype=float)
        # before the first scan every beam reads max range
        self._scans = [np.full(len(a), r) for a, r in zip(self._angles, self._rmax, strict=True)]

    def _view(self, i: int) -> ScanView:
        readings = self.env.last_readings
        if readings is not None and readings.range_mask[i]:
            row = np.asarray(readings.ranges[i][: len(self._angles[i])], dtype=float)
            self._scans[i] = np.where(np.isfinite(row), row, self._rmax[i])
        return ScanView(self._scans[i], self._angles[i], float(self._rmax[i]))

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One wander action per live agent."""
        index = self.env.agent_name_mapping
        return {a: wander(self._view(index[a]), self.rng, self.speed) for a in self.env.agents}
