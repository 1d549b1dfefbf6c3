"""``corridor``: follow the free space ahead at full speed, by the robot's own range scan.

The classical reactive answer to "drive so that the sensors see as much of
the world as possible": each robot steers toward the direction ahead with the
most free space (a beam's range, less a penalty per radian off the current
heading, so it keeps going rather than turning back), is pushed away from
the nearer side wall, slows down when the way ahead closes in, and turns in
place when something is right in front. It needs no belief at all, so it is
the natural exploration baseline for global localization: in a ring of
corridors it keeps circling instead of reversing at random, and passes the
symmetry-breaking feature within one lap.

Reads only the robot's own last scan (``env.last_readings`` with
``env.sensors.beam_angles``, as :class:`policies.scripted.wander.WanderPolicy`); never the
true poses.
"""

from __future__ import annotations

import numpy as np

from policies.scripted.view import ScanView
from policies.scripted.wander import WanderPolicy

TURN_PENALTY = 0.8  # m of free range given up per radian off the current heading
SIDE = (1.2, 1.95)  # rad: the sectors (each side) that measure the clearance to the side walls
SIDE_GAIN = 0.5  # rad of steering per metre of clearance difference (clipped at 1 m)
CLOSE = 0.6  # m: anything nearer than this ahead makes the robot turn in place
SLOW = 2.0  # m: the robot slows down linearly when the way ahead is nearer than this


def follow(view: ScanView, speed: float = 1.0, gain: float = 3.0) -> np.ndarray:
    """One corridor-following action ``[forward, turn]`` from a robot's own scan."""
    bearing = np.arctan2(np.sin(view.angles), np.cos(view.angles))
    ahead = np.abs(bearing) <= np.pi / 2 + 1e-6
    score = np.where(ahead, np.minimum(view.ranges, view.max_range) - TURN_PENALTY
                     * np.abs(bearing), -np.inf)
    err = float(bearing[int(np.argmax(score))])
    left, right = view.min_range(*SIDE), view.min_range(-SIDE[1], -SIDE[0])
    if view.min_range(-0.8, 0.8) < CLOSE:
        return np.array([0.0, 0.8 if left >= right else -0.8], dtype=np.float32)
    err += SIDE_GAIN * float(np.clip(left - right, -1.0, 1.0))
    slow = min(1.0, view.min_range(-0.4, 0.4) / SLOW)
    forward = speed * max(0.0, np.cos(err)) ** 2 * slow
    return np.array([forward, np.clip(gain * err, -1.0, 1.0)], dtype=np.float32)


class CorridorPolicy(WanderPolicy):
    """Every robot follows the free space ahead (:func:`follow`) at ``speed`` in (0, 1]."""

    name = "corridor"

    def __init__(self, speed: float = 1.0, gain: float = 3.0) -> None:
        super().__init__(speed)
        if not gain > 0:
            raise ValueError(f"gain must be > 0, got {gain!r}")
        self.gain = float(gain)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One corridor-following action per live agent."""
        index = self.env.agent_name_mapping
        return {a: follow(self._view(index[a]), self.speed, self.gain) for a in self.env.agents}
