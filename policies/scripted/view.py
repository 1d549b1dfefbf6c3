"""What one robot knows, gathered from the env's public interface.

Policies in this package act on :class:`RobotView` records only: the robot's
own belief (estimated pose and covariance), its latched sensor features from
its observation (inclinometer pitch/roll, min-pooled range bins) and its camera
sightings; or, for the reactive behaviours, on a :class:`ScanView` of the
robot's own last range scan, beam by beam. Nothing here reads the true poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coop_loc_env.depth_from_motion import CameraRecord
from coop_loc_env.env import CoopLocParallelEnv


@dataclass
class RobotView:
    """One robot's knowledge at one step.

    Attributes:
        index: the robot's index in the team.
        est_pose: estimated ``(x, y, heading)``.
        pose_cov: ``(3, 3)`` covariance of ``est_pose``.
        pitch, roll: last inclinometer reading (rad).
        incl_new: whether the inclinometer produced that reading this step.
        ranges: min-pooled range bins (m), ``max_range`` where nothing returned.
        bin_lo, bin_hi: angular extent of each bin in the robot frame (rad).
        max_range: the range sensor's maximum range (m).
        camera: this step's camera records (empty when the camera took no frame).
        camera_frame: whether the camera took a frame this step.
        teammates: estimated poses ``(n, 3)`` the team shares (row ``index`` is self).
        team_objects: ``(k, 2)`` objects of interest the team has marked on its map.
        world_size: ``(W, H)`` of the mapped area.
        dt: env step (s).
    """

    index: int
    est_pose: np.ndarray
    pose_cov: np.ndarray
    pitch: float
    roll: float
    incl_new: bool
    ranges: np.ndarray
    bin_lo: np.ndarray
    bin_hi: np.ndarray
    max_range: float
    camera: list[CameraRecord]
    camera_frame: bool
    teammates: np.ndarray
    team_objects: np.ndarray
    world_size: tuple[float, float]
    dt: float

    @property
    def slope(self) -> float:
        """Terrain slope (rad) under the robot from the last pitch and roll readings."""
        return float(np.arctan(np.hypot(np.tan(self.pitch), np.tan(self.roll))))

    @property
    def position_std(self) -> float:
        """RMS per-axis position standard deviation (m) of the belief."""
        return float(np.sqrt(0.5 * (self.pose_cov[0, 0] + self.pose_cov[1, 1])))

    def min_range(self, lo: float, hi: float) -> float:
        """Nearest return (m) in bins overlapping the robot-frame sector ``[lo, hi]``."""
        sel = (self.bin_hi >= lo) & (self.bin_lo <= hi)
        return float(self.ranges[sel].min()) if sel.any() else self.max_range


class ViewBuilder:
    """Builds :class:`RobotView` records for the agents of one env."""

    def __init__(self, env: CoopLocParallelEnv) -> None:
        self.env = env
        names = env.observations.names
        cfg = env.config
        self._i_pitch = names.index("pitch")
        self._i_roll = names.index("roll")
        self._i_range = names.index("range_bin_0")
        bins = cfg.laser_obs_bins
        self._bins = bins
        self._lo, self._hi = [], []
        for angles in env.sensors.beam_angles:
            beams = len(angles)
            starts = np.minimum(np.floor(np.linspace(0, beams, bins + 1)[:-1]).astype(int),
                                beams - 1)
            ends = np.append(starts[1:], beams)
            ends = np.maximum(ends, starts + 1)
            spans = list(zip(starts, ends, strict=True))
            self._lo.append(np.array([angles[s:e].min() for s, e in spans]))
            self._hi.append(np.array([angles[s:e].max() for s, e in spans]))

    def view(self, agent: str, obs: np.ndarray | dict) -> RobotView:
        """``agent``'s view from its observation vector and its own sensors (a dict
        observation's ``"vector"`` starts with the same entries)."""
        if isinstance(obs, dict):
            obs = obs["vector"]
        env = self.env
        i = env.agent_name_mapping[agent]
        readings = env.last_readings
        rmax = float(env.sensors.range_max[i])
        ranges = np.asarray(obs[self._i_range : self._i_range + self._bins], dtype=float) * rmax
        return RobotView(
            index=i,
            est_pose=env.estimated_poses[i],
            pose_cov=env.estimated_covariances[i],
            pitch=float(obs[self._i_pitch]),
            roll=float(obs[self._i_roll]),
            incl_new=bool(readings is not None and readings.inclinometer_mask[i]),
            ranges=ranges,
            bin_lo=self._lo[i],
            bin_hi=self._hi[i],
            max_range=rmax,
            camera=env.camera_readings(agent),
            camera_frame=bool(readings is not None and readings.camera_mask[i]),
            teammates=env.estimated_poses,
            team_objects=np.array([o[:2] for o in env.terrain_map.objects]).reshape(-1, 2),
            world_size=tuple(env.config.world_size),
            dt=env.config.dt,
        )


class ScanView:
    """A robot's own last range scan, one entry per beam (what
    :func:`~policies.scripted.baselines.wander` reads)."""

    def __init__(self, ranges: np.ndarray, angles: np.ndarray, max_range: float) -> None:
        self.ranges = ranges
        self.angles = angles
        self.max_range = max_range

    def min_range(self, lo: float, hi: float) -> float:
        """Nearest return (m) of the beams pointing into the robot-frame sector ``[lo, hi]``."""
        sel = (self.angles >= lo) & (self.angles <= hi)
        return float(self.ranges[sel].min()) if sel.any() else self.max_range
