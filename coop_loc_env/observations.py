"""Observation builder: what a robot knows (its belief and its own readings) as one vector.

Layout of an agent's observation (float32, every entry clipped to [-10, 10]):

=====================  ==========================  ===========================================
block                  size                        content
=====================  ==========================  ===========================================
belief                 ``belief_size``             the estimator backend's features, zero-padded
                                                   (EKF: ``estimation.gaussian_features``; MLE:
                                                   the same 10 plus the estimated relative poses
                                                   of the K nearest teammates, 6 per slot, see
                                                   ``coop_loc_env.mle_backend``; MCL: 48
                                                   values, the same 10 first, then particle
                                                   statistics and histograms, layout in
                                                   ``particle_filter.belief_feature_names``)
gps                    2                           fix held (0/1), satellites in view / 12, as of
                                                   the last DGPS reading (also one with none)
inclinometer           2                           last pitch and roll (rad)
range                  ``laser_obs_bins``          min-pooled ranges / max range (1 = nothing)
detections             ``6 * max_detections_obs``  per slot, nearest first: present, range /
                                                   detector range, cos/sin bearing, cos/sin
                                                   orientation
last action            2                           the normalized action applied last step
teammates (optional)   11                          ``teammate_obs``: own GPS receiver (0/1);
                                                   then for the nearest teammate with GPS and
                                                   the nearest one without (by the estimates
                                                   the team shares): present, cos/sin bearing
                                                   in the robot's estimated frame, distance /
                                                   detector range, log10 position std
map patch (optional)   ``3 * map_patch_obs**2``    egocentric team-map patch (``map_patch_obs``
                                                   cells a side, ``map_resolution`` m apart,
                                                   axis 0 forward, axis 1 left, row-major),
                                                   three channels one after the other:
                                                   elevation minus the robot's own elevation
                                                   estimate (m, 0 where unmapped), mapped
                                                   (0/1), object of interest marked (0/1)
privileged (optional)  4                           true x/W*2-1, y/H*2-1, cos, sin heading
=====================  ==========================  ===========================================

The agent's own index is not in the observation, so one policy can be shared
by interchangeable robots.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from gymnasium import spaces

from coop_loc_env._step_kernels import pack_observations, pool_scans
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.records import Readings

OBS_LIMIT = 10.0


class ObservationBuilder:
    """Keeps each robot's latched sensor features and assembles observation vectors."""

    def __init__(self, cfg: ScenarioConfig, belief_size: int, belief_names: tuple[str, ...]):
        self.cfg = cfg
        self.belief_size = belief_size
        self.names = self._names(belief_names)
        self.size = len(self.names)
        self.space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(self.size,), dtype=np.float32)
        n = cfg.n_robots
        # The latched features side by side, in observation order, so that one copy
        # moves them all: gps (2), incl (2), range bins, detections; each a view.
        self._latched = np.zeros((n, 4 + cfg.laser_obs_bins + 6 * cfg.max_detections_obs))
        self._bind_views()
        # Only belief, latched features and the last action: build_all packs them compiled.
        self._plain = not (cfg.teammate_obs or cfg.map_patch_obs or cfg.privileged_obs) and (
            self.size == belief_size + self._latched.shape[1] + 2)
        self.range[:] = 1.0
        self._det_written = False

    def _bind_views(self) -> None:
        """``gps``, ``incl``, ``range`` and ``det``: column blocks of ``_latched``."""
        bins = self.cfg.laser_obs_bins
        self.gps = self._latched[:, 0:2]
        self.incl = self._latched[:, 2:4]
        self.range = self._latched[:, 4 : 4 + bins]
        self.det = self._latched[:, 4 + bins :]

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("gps", "incl", "range", "det"):  # views: rebuilt on unpickling
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind_views()

    def _names(self, belief_names: tuple[str, ...]) -> list[str]:
        cfg = self.cfg
        names = list(belief_names) + [
            f"belief_pad_{i}" for i in range(self.belief_size - len(belief_names))
        ]
        names += ["gps_fix", "gps_satellites", "pitch", "roll"]
        names += [f"range_bin_{i}" for i in range(cfg.laser_obs_bins)]
        for k in range(cfg.max_detections_obs):
            fields = ("present", "range", "cos_bearing", "sin_bearing", "cos_orient", "sin_orient")
            names += [f"det{k}_{f}" for f in fields]
        names += ["last_v", "last_w"]
        if cfg.teammate_obs:
            names += ["team_own_gps"] + [
                f"team_{kind}_{f}" for kind in ("gps", "nogps")
                for f in ("present", "cos_bearing", "sin_bearing", "range", "log10_std")
            ]
        size = cfg.map_patch_obs
        for channel in ("elev", "mapped", "object"):
            names += [f"map_{channel}_{u}_{v}" for u in range(size) for v in range(size)]
        if cfg.privileged_obs:
            names += ["true_x", "true_y", "true_cos_heading", "true_sin_heading"]
        return names

    def reset(self) -> None:
        """Forget latched readings (start of an episode)."""
        self.gps[:] = 0.0
        self.incl[:] = 0.0
        self.range[:] = 1.0
        self.det[:] = 0.0
        self._det_written = False

    @property
    def latched_pitch(self) -> np.ndarray:
        """Each robot's last inclinometer pitch ``(n,)`` (a view; 0 before any reading)."""
        return self.incl[:, 0]

    def ingest(self, readings: Readings, max_range: np.ndarray) -> None:
        """Latch the sensor features of one env step.

        The GPS features are refreshed on every step the DGPS receivers report,
        also when none of them sees a satellite (the fix is then lost).
        """
        cfg = self.cfg
        if readings.fired.gps:  # DGPS
            self.gps[:, 0] = readings.gps_mask
            self.gps[:, 1] = readings.satellites / 12.0
        m = readings.inclinometer_mask
        if np.count_nonzero(m):
            self.incl[m, 0] = readings.pitch[m]
            self.incl[m, 1] = readings.roll[m]
        m = readings.range_mask
        fired = np.count_nonzero(m)
        if fired:  # each scanning robot's row pooled on its own (the others keep theirs)
            ranges = readings.ranges
            pool_scans(ranges, np.asarray(max_range, dtype=float),
                       _pool_starts(ranges.shape[1], cfg.laser_obs_bins), m, self.range)
        det = readings.detections
        if self._det_written:
            self.det[:] = 0.0
            self._det_written = False
        if len(det):
            self._det_written = True
            order = np.lexsort((det.z[:, 0], det.observer)).tolist()
            observer, z = det.observer.tolist(), det.z.tolist()
            slot = [0] * cfg.n_robots
            for k in order:
                i = observer[k]
                s = slot[i]
                if s >= cfg.max_detections_obs:
                    continue
                r, b, o = z[k]
                self.det[i, 6 * s : 6 * s + 6] = (
                    1.0, r / cfg.detector_range, math.cos(b), math.sin(b), math.cos(o), math.sin(o)
                )
                slot[i] = s + 1

    def build_all(
        self,
        belief: np.ndarray,
        last_action: np.ndarray,
        true_poses: np.ndarray,
        map_patch: np.ndarray | None = None,
        teammates: np.ndarray | None = None,
    ) -> np.ndarray:
        """Observation matrix of all robots ``(n, size)`` from belief features ``(n, b)``.

        ``map_patch`` ``(n, 3, S, S)`` is required when ``map_patch_obs = S > 0``,
        ``teammates`` (:func:`teammate_features`) when ``teammate_obs`` is on.
        """
        cfg = self.cfg
        n = len(belief)
        if self._plain and belief.shape[1] <= self.belief_size and last_action.shape[1] == 2:
            obs = np.empty((n, self.size), dtype=np.float32)  # the blocks in one pass
            pack_observations(belief, self._latched, last_action, self.belief_size, OBS_LIMIT,
                              obs)
            return obs
        parts = [belief, self._latched, last_action]  # _latched: gps, incl, range, det
        if cfg.teammate_obs:
            if teammates is None:
                raise ValueError("teammates is required when teammate_obs is on, got None")
            parts.append(teammates)
        if cfg.map_patch_obs:
            if map_patch is None:
                raise ValueError("map_patch is required when map_patch_obs > 0, got None")
            parts.append(np.asarray(map_patch).reshape(n, -1))
        if cfg.privileged_obs:
            w, h = cfg.world_size
            x, y, th = true_poses.T
            parts.append(np.stack([x / w * 2 - 1, y / h * 2 - 1, np.cos(th), np.sin(th)], 1))
        # Each block cast to float32 in place of one concatenated float64 matrix.
        obs = np.empty((n, self.size), dtype=np.float32)
        if belief.shape[1] < self.belief_size:
            obs[:, belief.shape[1] : self.belief_size] = 0.0  # belief padding
        start = 0
        for part in parts:
            width = part.shape[1]
            obs[:, start : start + width] = part
            start += width + (self.belief_size - width if part is belief else 0)
        np.maximum(obs, -OBS_LIMIT, out=obs)
        return np.minimum(obs, OBS_LIMIT, out=obs)


def teammate_features(
    mean: np.ndarray, cov: np.ndarray, has_gps: np.ndarray, live: np.ndarray, scale: float
) -> np.ndarray:
    """``(n, 11)`` per robot: own GPS flag, then for the nearest live teammate with GPS and
    the nearest without: present, cos/sin bearing in the robot's estimated frame, distance
    / ``scale``, log10 RMS position std (the layout of the observation's teammates block).

    Computed from the estimates the team shares (``mean (n, 3)``, ``cov (n, 3, 3)``),
    never the true poses.
    """
    n = len(mean)
    out = np.zeros((n, 11))
    out[:, 0] = has_gps
    rel = mean[None, :, :2] - mean[:, None, :2]  # rel[i, j]: from i to j
    dist = np.hypot(rel[..., 0], rel[..., 1])
    bearing = np.arctan2(rel[..., 1], rel[..., 0]) - mean[:, 2:3]
    log_std = np.log10(np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 1e-12)))
    mate = live[None, :] & ~np.eye(n, dtype=bool)
    for col, kind in ((1, has_gps), (6, ~has_gps)):
        d = np.where(mate & kind[None, :], dist, np.inf)
        j = np.argmin(d, axis=1)
        rows = np.arange(n)
        present = np.isfinite(d[rows, j])
        b = bearing[rows, j]
        block = np.stack([np.ones(n), np.cos(b), np.sin(b), dist[rows, j] / scale,
                          log_std[j]], axis=1)
        out[:, col : col + 5] = np.where(present[:, None], block, 0.0)
    return out


@functools.lru_cache(maxsize=64)
def _pool_starts(beams: int, bins: int) -> np.ndarray:
    return np.minimum(np.floor(np.linspace(0, beams, bins + 1)[:-1]).astype(int), beams - 1)
