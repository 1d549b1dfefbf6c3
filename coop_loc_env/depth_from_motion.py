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
from coop_loc_env.records import CameraSightings


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
        sightings: CameraSightings | None = None,
    ) -> list[list[CameraRecord]]:
        """Turn one step's camera sightings into depth-from-motion records.

        Args:
            camera: per robot, ``(kind, id, bearing, range)`` sightings from the
                sensor model (only kind, id and bearing are kept).
            camera_mask: robots whose camera took a frame this step.
            poses: true robot poses ``(n, 3)`` (the camera's true motion).
            ooi_centers: positions of the objects of interest ``(k, 2)``.
            rng: the episode's noise generator (draws a new track's error).
            sightings: the same sightings as arrays (``Readings.camera_sightings``);
                when given, ``camera`` is not read and the geometry is not recomputed.

        Returns:
            Per robot, the :class:`CameraRecord` list of this frame (empty for
            robots whose camera did not fire).
        """
        n = len(poses)
        out: list[list[CameraRecord]] = [[] for _ in range(n)]
        fired = np.asarray(camera_mask)
        rows = fired.nonzero()[0].tolist()
        if not rows:
            return out
        # Index of the robots whose camera fired (a slice for the whole team).
        sel = slice(None) if len(rows) == n else fired.nonzero()[0]
        if sightings is None:
            sightings = self._sightings_of(camera, rows, poses, ooi_centers)
        if not len(sightings.bearing):  # nothing in view: every track of these robots ends
            self.frames[sel] = 0
            self.baseline[sel] = 0.0
            self.last_pose[sel] = poses[sel]
            return out
        std, estimate, frames = self._track(sightings, poses, sel, rng)
        n_ooi = self.n_ooi
        for b, i, t, s, r, f in zip(
            sightings.bearing, sightings.observer.tolist(), sightings.target.tolist(),
            std.tolist(), estimate.tolist(), frames.tolist(), strict=True,
        ):
            kind, ident = ("ooi", t) if t < n_ooi else ("robot", t - n_ooi)
            out[i].append(CameraRecord(kind, ident, float(b), max(r, 0.1), s, f))
        return out

    def _sightings_of(
        self,
        camera: list[list[tuple[str, int, float, float]]],
        rows: list[int],
        poses: np.ndarray,
        ooi_centers: np.ndarray,
    ) -> CameraSightings:
        """The ``camera`` lists of robots ``rows`` as sightings in (robot, target) order,
        with the lines of sight computed from the true ``poses``."""
        n_ooi, n_targets = self.n_ooi, self.frames.shape[1]
        keys = {
            i * n_targets + (ident if kind == "ooi" else n_ooi + ident): bearing
            for i in rows
            for kind, ident, bearing, _rng in camera[i]
        }
        key = np.fromiter(sorted(keys), dtype=np.intp, count=len(keys))
        pi, pt = np.divmod(key, n_targets)
        if n_ooi:
            targets = np.concatenate([np.asarray(ooi_centers).reshape(-1, 2), poses[:, :2]])
        else:
            targets = poses[:, :2]
        los = targets[pt] - poses[pi, :2]
        dist = np.maximum(np.hypot(los[:, 0], los[:, 1]), 1e-6)
        return CameraSightings(pi, pt, [keys[k] for k in key.tolist()], los, dist)

    def _track(
        self, sightings: CameraSightings, poses: np.ndarray, sel: slice | np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continue, start and end the tracks of the robots ``sel`` whose camera fired;
        returns each sighting's range std, range estimate and frames tracked."""
        frames, baseline, last_pose = self.frames, self.baseline, self.last_pose
        pi, pt = sightings.observer, sightings.target
        key = pi * frames.shape[1]
        key += pt
        move = poses[pi, :2] - last_pose[pi, :2]  # (k, 2)
        los, dist = sightings.offset, sightings.dist  # dist > 1e-6
        ux, uy = los[:, 0] / dist, los[:, 1] / dist
        mx, my = move[:, 0], move[:, 1]
        along = self.cfg.camera_looming_gain * (mx * ux + my * uy)
        perp = mx * uy - my * ux
        step_base = np.sqrt(perp**2 + along**2)
        flat_frames, flat_base = frames.reshape(-1), baseline.reshape(-1)
        count = flat_frames[key]
        cont = count > 0
        base = np.where(cont, flat_base[key] + step_base, 0.0)
        # Every other track of these robots ends.
        frames[sel] = 0
        baseline[sel] = 0.0
        flat_frames[key] = count + 1
        flat_base[key] = base
        if np.count_nonzero(cont) < cont.size:
            fresh = key[~cont]
            self.xi.reshape(-1)[fresh] = rng.standard_normal(fresh.size)
        last_pose[sel] = poses[sel]
        info = (base / (dist**2 * max(self.sigma_theta, 1e-12))) ** 2
        std = 1.0 / np.sqrt(1.0 / self.prior_var + info)
        return std, dist + std * self.xi.reshape(-1)[key], count + 1
