"""``dispersal``: Howard et al.'s behaviour, spreading a crowded team by each robot's own sensors.

:class:`DispersalPolicy` steers towards long free laser beams pointing away from
the teammates its robot detector sees; it reads no belief and no true pose.
"""

from __future__ import annotations

import numpy as np

from estimators.geometry import wrap_angle


class DispersalPolicy:
    """Howard-style dispersal from each robot's own laser scan and robot detections.

    A potential field in the robot's frame: a constant pull forward, a push
    away from every laser return closer than ``influence_m`` (walls and
    teammates alike) and a push away from the teammates the robot detector
    sees (remembered for ``memory_s`` seconds, since the detector may run
    slower than the env). The robot turns towards the resulting vector and
    drives at a speed that falls with the clearance ahead.

    Args:
        away_weight: weight of the push away from detected teammates.
        obstacle_weight: weight of the push away from close laser returns.
        influence_m: laser returns closer than this push.
        clearance_m: obstacle distance ahead over which the robot slows down.
        memory_s: how long a detected teammate keeps repelling.
        open_weight: pull towards the most open direction (the longest beam, a little
            biased forward), which leads robots through doorways.
    """

    name = "dispersal"

    def __init__(
        self,
        away_weight: float = 1.0,
        obstacle_weight: float = 0.4,
        influence_m: float = 1.5,
        clearance_m: float = 0.8,
        memory_s: float = 1.0,
        open_weight: float = 1.5,
    ) -> None:
        self.open_weight = open_weight
        self.away_weight = away_weight
        self.obstacle_weight = obstacle_weight
        self.influence_m = influence_m
        self.clearance_m = clearance_m
        self.memory_s = memory_s
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset)."""
        self.env = env
        n = env.config.n_robots
        self._away = np.zeros((n, 2))  # push away from teammates, in each robot's frame
        self._age = np.full(n, np.inf)
        self._angles = env.sensors.beam_angles
        self._max_range = env.sensors.range_max

    def _update_repulsion(self) -> None:
        env = self.env
        readings = env.last_readings
        self._age += env.config.dt
        if readings is None:
            return
        det = readings.detections
        if not len(det):
            return
        obs, r, b = det.observer, det.z[:, 0], det.z[:, 1]
        push = -np.stack([np.cos(b), np.sin(b)], 1) / np.maximum(r, 0.5)[:, None]
        fresh = np.zeros((env.config.n_robots, 2))
        np.add.at(fresh, obs, push)
        seen = np.unique(obs)
        self._away[seen] = fresh[seen]
        self._age[seen] = 0.0

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent."""
        env = self.env
        self._update_repulsion()
        readings = env.last_readings
        out = {}
        for agent in env.agents:
            i = env.agent_name_mapping[agent]
            angles = self._angles[i]
            if readings is None or not readings.range_mask[i]:
                out[agent] = np.array([0.5, 0.0], dtype=np.float32)
                continue
            ranges = np.nan_to_num(readings.ranges[i, : len(angles)], nan=self._max_range[i])
            close = np.clip((self.influence_m - ranges) / np.maximum(ranges, 0.1), 0.0, None)
            units = np.stack([np.cos(angles), np.sin(angles)], 1)
            force = np.array([1.0, 0.0]) - self.obstacle_weight * close @ units
            free = np.minimum(ranges, self._max_range[i])
            force += self.open_weight * units[int(np.argmax(free + 0.5 * np.cos(angles)))]
            if self._age[i] <= self.memory_s:
                force += self.away_weight * self._away[i]
            target = float(np.arctan2(force[1], force[0]))
            ahead = np.abs(wrap_angle(angles)) <= np.pi / 4
            front = ranges[ahead].min() if ahead.any() else self._max_range[i]
            speed = np.clip((front - 0.4) / self.clearance_m, 0.0, 1.0) * max(np.cos(target), 0.0)
            turn = np.clip(2.0 * target, -1.0, 1.0)
            out[agent] = np.array([speed, turn], dtype=np.float32)
        return out
