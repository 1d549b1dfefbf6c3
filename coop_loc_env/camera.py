"""The camera pipeline, run when its output is read.

No observation, reward or estimator of the env uses the camera: its records
feed the scripted policies (:mod:`policies.scripted.fsm`) and whoever calls
:meth:`~coop_loc_env.env.CoopLocParallelEnv.camera_readings`. So a step only
queues its camera frame (the true poses, and which cameras fired), and the
sensor model (:meth:`~coop_loc_env.sensors.SensorSuite.camera_frame`) and depth
from motion (:class:`~coop_loc_env.depth_from_motion.DepthFromMotion`) run over
the queued frames, in order, when the records are first read. The camera
draws from its own random stream, so its records are the same whenever (and
whether) they are read, and the rest of the env does not depend on them.
"""

from __future__ import annotations

import numpy as np

from coop_loc_env.depth_from_motion import DepthFromMotion
from coop_loc_env.records import CameraOutput, LazyCamera
from coop_loc_env.sensors import SensorSuite

MAX_PENDING_BYTES = 32 * 2**20  # queued frames beyond this are processed (bounds memory)


class CameraPipeline:
    """Camera frames turned into depth-from-motion records on demand.

    Args:
        sensors: the team's sensors (the camera model).
        depth: the depth-from-motion tracker the records come from.
        ooi_centers: positions of the objects of interest ``(k, 2)``.
    """

    def __init__(
        self, sensors: SensorSuite, depth: DepthFromMotion, ooi_centers: np.ndarray
    ) -> None:
        self.sensors = sensors
        self.depth = depth
        self.ooi_centers = ooi_centers
        self.n = sensors.cfg.n_robots
        self._rng = np.random.default_rng(0)
        # The queue: true poses and camera masks of the frames not processed yet.
        self._poses = np.zeros((0, self.n, 3))
        self._masks = np.zeros((0, self.n), dtype=bool)
        self._pending = 0
        self._queued = 0  # frames queued this episode (the next frame's number)
        self._done = 0  # frames processed this episode
        self._last: CameraOutput | None = None  # the output of frame ``_done - 1``
        # The lazy outputs of the queued frames, in frame order: each gets its value when
        # its frame is processed and leaves the list (so it holds no more than the queue).
        self._waiting: list[LazyCamera] = []

    def reset(self, poses: np.ndarray, rng: np.random.Generator) -> None:
        """Forget every track; the camera's stream is seeded from one draw of ``rng``
        (none for a team without cameras)."""
        self.depth.reset(poses)
        if self.sensors.has_camera.any():
            self._rng = np.random.default_rng(int(rng.integers(2**63)))
        self._pending = self._queued = self._done = 0
        self._last = None
        self._waiting.clear()

    def add_step(self, poses: np.ndarray, camera_mask: np.ndarray) -> LazyCamera | None:
        """Queue this step's frame: ``poses`` are the true poses, ``camera_mask`` the
        robots whose camera fired. Returns the frame's output, computed when first read
        (``None``: no frame, ``camera_mask`` all False)."""
        if not np.count_nonzero(camera_mask):
            return None
        frame = LazyCamera(self, self._queued)
        self._waiting.append(frame)
        self._queued += 1
        k = self._pending
        if k == len(self._poses):
            self._make_room()
            k = self._pending
        self._poses[k] = poses
        self._masks[k] = camera_mask
        self._pending = k + 1
        return frame

    def _make_room(self) -> None:
        """Grow the queue (doubling), or process its older half once it holds
        ``MAX_PENDING_BYTES``."""
        cap = len(self._poses)
        limit = max(2, MAX_PENDING_BYTES // (self.n * (self._poses.itemsize * 3 + 1)))
        if cap < limit:
            grown = min(max(2 * cap, 64), limit)
            poses = np.zeros((grown, self.n, 3))
            masks = np.zeros((grown, self.n), dtype=bool)
            poses[:cap], masks[:cap] = self._poses, self._masks
            self._poses, self._masks = poses, masks
        else:
            self._process(cap // 2)

    def _process(self, count: int) -> None:
        """Run the camera model and depth from motion over the ``count`` oldest frames."""
        for poses, mask, lazy in zip(self._poses[:count], self._masks[:count],
                                     self._waiting[:count], strict=True):
            _, sightings = self.sensors.camera_frame(poses, self._rng, mask)
            records = self.depth.process(
                [], mask, poses, self.ooi_centers, self._rng, sightings
            )
            self._last = CameraOutput(None, sightings, records)
            lazy.resolve(self._last)
            self._done += 1
        del self._waiting[:count]
        rest = self._pending - count
        self._poses[:rest] = self._poses[count : self._pending]
        self._masks[:rest] = self._masks[count : self._pending]
        self._pending = rest

    def output_of(self, frame: int) -> CameraOutput:
        """The output of this episode's frame number ``frame`` (processing the queue up
        to it; an earlier frame's output went to its :class:`LazyCamera`)."""
        if frame >= self._done:
            self._process(frame + 1 - self._done)
        if frame == self._done - 1 and self._last is not None:
            return self._last
        raise RuntimeError(f"camera frame {frame} of this episode is no longer available")
