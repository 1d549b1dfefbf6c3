"""Camera range as depth from motion (Madhavan, Fregene, Parker, Sec. 5.2).

A single camera frame gives a bearing (pixel offset) but no range. Range comes
from the robot's own motion while it keeps the object in view: the parallax
accumulated over the baseline the camera travelled triangulates the object,
and the estimate is refined frame by frame. We model the *outcome* of that
process rather than optical flow itself:

* A *track* starts when an object enters the camera's view. Its range
  estimate starts with standard deviation ``camera_range_std`` (a monocular
  guess from apparent size).
* Every camera frame adds the camera's displacement since the previous frame
  to the track's effective baseline ``B``: the component perpendicular to the
  line of sight in full (parallax), the component along it weighted by
  ``camera_looming_gain`` (range from image expansion is less informative).
* Triangulating with bearing noise ``sigma_theta = camera_flow_std_px`` pixels
  gives a range error of ``r^2 sigma_theta / B``; fused with the prior, the
  track's range variance is ``1 / (1 / camera_range_std^2 + (B / (r^2 sigma_theta))^2)``.
* The reported range is ``r_true + std * xi``, with ``xi ~ N(0, 1)`` drawn once
  per track, so successive estimates of one track are consistent (the error
  shrinks with the standard deviation instead of jumping).
* When the object leaves the view (or the camera misses a frame of it) the
  track ends; seeing it again starts a new one.

So a robot that stands still keeps its first, poor range; one that moves
while keeping the object in view sees the range noise shrink.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coop_loc_env.config import ScenarioConfig


@dataclass(frozen=True)
class CameraRecord:
    """One object seen by a robot's camera in one frame.

    Attributes:
        kind: ``"ooi"`` (object of interest) or ``"robot"``.
        id: the object's index among objects of interest, or the robot index.
        bearing: pixel-quantized bearing in the robot frame (rad, left positive).
        range: depth-from-motion range estimate (m).
        range_std: standard deviation of ``range`` (m); shrinks while tracked.
        frames: consecutive frames the object has been tracked, including this one.
    """

    kind: str
    id: int
    bearing: float
    range: float
    range_std: float
    frames: int


class DepthFromMotion:
    """Per-robot, per-target depth-from-motion tracks for the camera.

    Args:
        cfg: the scenario (camera field of view, width, range std, flow noise).
        n_ooi: number of objects of interest (targets ``0 .. n_ooi - 1``; robots follow).
    """

    def __init__(self, cfg: ScenarioConfig, n_ooi: int) -> None:
        self.cfg = cfg
        self.n_ooi = int(n_ooi)
        n = cfg.n_robots
        n_targets = self.n_ooi + n
        px = np.deg2rad(cfg.camera_fov_deg) / cfg.camera_width_px
        self.sigma_theta = cfg.camera_flow_std_px * px
        self.prior_var = max(cfg.camera_range_std, 1e-6) ** 2
        self.baseline = np.zeros((n, n_targets))
        self.frames = np.zeros((n, n_targets), dtype=np.int64)
        self.xi = np.zeros((n, n_targets))
        self.last_pose = np.zeros((n, 3))

    def reset(self, poses: np.ndarray) -> None:
        """Forget every track (start of an episode)."""
        self.baseline[:] = 0.0
        self.frames[:] = 0
        self.xi[:] = 0.0
        self.last_pose[:] = poses

    def process(
        self,
        camera: list[list[tuple[str, int, float, float]]],
        camera_mask: np.ndarray,
        poses: np.ndarray,
        ooi_centers: np.ndarray,
        rng: np.random.Generator,
    ) -> list[list[CameraRecord]]:
        """Turn one step's camera sightings into depth-from-motion records.

        Args:
            camera: per robot, ``(kind, id, bearing, range)`` sightings from the
                sensor model (only kind, id and bearing are kept).
            camera_mask: robots whose camera took a frame this step.
            poses: true robot poses ``(n, 3)`` (the camera's true motion).
            ooi_centers: positions of the objects of interest ``(k, 2)``.
            rng: the episode's noise generator (draws a new track's error).

        Returns:
            Per robot, the :class:`CameraRecord` list of this frame (empty for
            robots whose camera did not fire).
        """
        cfg = self.cfg
        n = len(poses)
        out: list[list[CameraRecord]] = [[] for _ in range(n)]
        frames_robots = np.flatnonzero(camera_mask)
        if frames_robots.size == 0:
            return out
        targets = np.concatenate([np.asarray(ooi_centers).reshape(-1, 2), poses[:, :2]], axis=0)
        seen = np.zeros_like(self.frames, dtype=bool)
        for i in frames_robots:
            for kind, ident, _bearing, _rng in camera[i]:
                seen[i, ident if kind == "ooi" else self.n_ooi + ident] = True
        rows = frames_robots
        if not seen[rows].any():  # nothing in view: every track of these robots ends
            self.frames[rows] = 0
            self.baseline[rows] = 0.0
            self.last_pose[rows] = poses[rows]
            return out
        # Tracks that continue: accumulate the baseline since the previous frame.
        move = poses[rows, :2] - self.last_pose[rows, :2]  # (r, 2)
        los = targets[None, :, :] - poses[rows, None, :2]  # (r, T, 2)
        dist = np.maximum(np.hypot(los[..., 0], los[..., 1]), 1e-6)
        u = los / dist[..., None]
        along = np.einsum("rd,rtd->rt", move, u)
        perp = move[:, None, 0] * u[..., 1] - move[:, None, 1] * u[..., 0]
        step_base = np.sqrt(perp**2 + (cfg.camera_looming_gain * along) ** 2)
        cont = seen[rows] & (self.frames[rows] > 0)
        new = seen[rows] & ~cont
        self.baseline[rows] = np.where(cont, self.baseline[rows] + step_base, 0.0)
        self.frames[rows] = np.where(seen[rows], self.frames[rows] + 1, 0)
        fresh_r, fresh_t = np.nonzero(new)
        if fresh_r.size:
            self.xi[rows[fresh_r], fresh_t] = rng.standard_normal(fresh_r.size)
        self.last_pose[rows] = poses[rows]
        info = (self.baseline[rows] / (dist**2 * max(self.sigma_theta, 1e-12))) ** 2
        std = 1.0 / np.sqrt(1.0 / self.prior_var + info)  # (r, T)
        for k, i in enumerate(rows):
            for kind, ident, bearing, _rng in camera[i]:
                t = ident if kind == "ooi" else self.n_ooi + ident
                s = float(std[k, t])
                r = max(float(dist[k, t] + s * self.xi[i, t]), 0.1)
                out[i].append(CameraRecord(kind, int(ident), float(bearing), r, s,
                                           int(self.frames[i, t])))
        return out
