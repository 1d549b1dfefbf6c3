"""The team terrain map inside the env: elevation samples every step, coverage and map RMSE.

:class:`TeamMapper` wraps :class:`estimators.terrain_map.TerrainMap` (the
paper's DGPS/inclinometer elevation fusion and confidence-merged team map) and
feeds it what each robot knows, once per env step:

* its *estimated* pose and covariance (localization error corrupts the map);
* the last inclinometer pitch it read (latched between 1 Hz readings; the
  observation builder keeps the latch, the map reads it);
* the signed distance it drove since the previous step, from its odometry;
* its DGPS altitude and satellite count on steps with a fix (NaN / 0 otherwise).

The two elevation sources are blended with the paper's satellite-count weights
(``map_fusion_weights="paper"``) or the variance-optimal Kalman gain
(``"kalman"``, several times smaller map RMSE with the default noise).

The coverage *reward* is counted on the ground truth, not on the map:
:meth:`TeamMapper.step` also marks, for each robot, the drivable cells its
footprint covers at its *true* pose, and :attr:`TeamMapper.last_covered_cells`
holds the cells each robot covered first (no robot of the team had covered them
before). Estimate drift moves where the map writes, so counting newly mapped
cells would pay a robot whose belief wanders; the map itself stays built from
the estimates.

The map frame is the true height field's frame: the DGPS base station's
altitude ``gps_base_altitude`` maps to elevation 0 (``datum = 0``), so
:meth:`TeamMapper.map_rmse` compares the map with the height field directly.
The true heights at the map's cell centres and the drivable mask (not steep,
not inside an obstacle) are computed once, so the per-step metrics cost a few
vectorized operations over the grid.
"""

from __future__ import annotations

import math

import numpy as np

from coop_loc_env._step_kernels import cover_footprints
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.records import Beliefs, Readings
from coop_loc_env.world import World
from estimators.terrain_fusion import REF_NOS
from estimators.terrain_map import TerrainMap

#: Variance (m^2) of each robot's elevation estimate at the start of an episode.
INITIAL_ELEVATION_VAR = 0.01


class TeamMapper:
    """Builds the team elevation map from the robots' beliefs and readings.

    Args:
        cfg: the scenario (``map_resolution``, ``map_footprint_radius``,
            inclinometer/DGPS noise, ``gps_base_altitude``).
        world: the world whose terrain is mapped (truth used only for the
            metrics and for each robot's starting elevation).
    """

    def __init__(self, cfg: ScenarioConfig, world: World) -> None:
        self.cfg = cfg
        self.world = world
        n = cfg.n_robots
        self.map = TerrainMap(
            n,
            size=cfg.world_size,
            resolution=cfg.map_resolution,
            origin=(0.0, 0.0),
            datum=0.0,
            pitch_std=cfg.inclinometer_std,
            # The env's altitude std is gps_altitude_std at gps_reference_satellites;
            # TerrainMap specifies it at REF_NOS satellites (variance ~ 1 / NOS).
            gps_alt_std=cfg.gps_altitude_std * np.sqrt(cfg.gps_reference_satellites / REF_NOS),
            footprint_radius=cfg.map_footprint_radius,
            weights=cfg.map_fusion_weights,
        )
        xc, yc = self.map.cell_centers()
        centers = np.stack([xc.ravel(), yc.ravel()], axis=1)
        self.true_height = world.terrain.elevation(centers).reshape(self.map.shape)
        clear = world.layout.clearance(centers) > 0.0
        drivable = (~world.terrain.is_steep(centers)) & clear
        self.drivable = drivable.reshape(self.map.shape)
        self._drivable_flat = drivable
        self._n_drivable = max(int(drivable.sum()), 1)
        self._truth_flat = self.true_height.ravel()
        self._sq_error = 0.0  # running sum of squared map errors over mapped cells
        self._covered = 0  # mapped drivable cells
        self.map.merge_listener = self._on_merge
        self._all = np.arange(n)
        self._all.flags.writeable = False
        self._ids_cache: dict[bytes, np.ndarray] = {}
        self._no_fix_cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._dt_sub = cfg.dt / cfg.odometry_substeps
        self._gps_offset = self.map.datum - float(cfg.gps_base_altitude)
        self.last_new_cells = np.zeros(n, dtype=np.int64)
        self._truly_covered = np.zeros(self._drivable_flat.size, dtype=bool)
        self._footprint_cells = np.rint(self.map.footprint / cfg.map_resolution).astype(np.intp)
        self.last_covered_cells = np.zeros(n, dtype=np.int64)

    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape ``(nx, ny)`` (axis 0 = x, as in :class:`TerrainMap`)."""
        return self.map.shape

    def reset(self, true_poses: np.ndarray, est_mean: np.ndarray, est_cov: np.ndarray) -> None:
        """Clear the map; each robot starts knowing its elevation (variance 0.01 m^2).

        Each robot then maps the ground it stands on, at its estimated start
        pose, so the map (and :meth:`map_rmse`) is defined from the first step.
        """
        z0 = self.world.terrain.elevation(np.asarray(true_poses)[:, :2])
        self.map.reset(initial_elevation=z0, initial_var=INITIAL_ELEVATION_VAR)
        self._sq_error = 0.0
        self._covered = 0
        n = self.cfg.n_robots
        zeros = np.zeros(n)
        self.map.update(  # with self._all, which the map then knows as checked
            self._all, est_mean, est_cov, zeros, np.full(n, np.nan), zeros, zeros,
            self.cfg.gps_base_altitude,
        )
        self.last_new_cells = np.zeros(n, dtype=np.int64)
        self._truly_covered[:] = False
        self.cover(np.asarray(true_poses, dtype=float), self._all)
        self.last_covered_cells = np.zeros(n, dtype=np.int64)

    def cover(self, true_poses: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Mark the drivable cells the footprints of robots ``ids`` cover at their true poses.

        The footprint is the map's, centred on the cell holding the true position.
        Returns the number of cells each robot of the team covered first ``(n,)``;
        a cell two robots reach in the same call counts for the lower index.
        """
        new = np.zeros(self.cfg.n_robots, dtype=np.int64)
        if ids.size:  # one compiled pass over the robots' footprints
            nx, ny = self.map.shape
            cover_footprints(np.asarray(true_poses, dtype=float), np.asarray(ids, dtype=np.intp),
                             1.0 / self.map.resolution, self._footprint_cells, nx, ny,
                             self._drivable_flat, self._truly_covered, new)
        return new

    def step(
        self,
        readings: Readings,
        beliefs: Beliefs,
        active: np.ndarray,
        pitch: np.ndarray,
        true_poses: np.ndarray | None = None,
    ) -> np.ndarray:
        """Register one elevation sample per active robot; returns newly mapped cells ``(n,)``.

        Args:
            readings: this step's sensor readings (odometry, DGPS).
            beliefs: the team's beliefs after this step's update (estimated poses
                ``mean (n, 3)`` and covariances ``cov (n, 3, 3)``).
            active: robots still in the episode (others are not sampled).
            pitch: each robot's last inclinometer pitch ``(n,)`` (latched between readings).
            true_poses: the robots' true poses ``(n, 3)``; when given, the cells
                the active robots truly covered first are left in
                :attr:`last_covered_cells` (zeros otherwise).
        """
        est_mean, est_cov = beliefs.mean, beliefs.cov
        pitch = np.ascontiguousarray(pitch)  # (a column of the latched readings)
        whole = np.count_nonzero(active) == active.size
        ids = self._all if whole else self._active_ids(active)
        if true_poses is not None:
            self.last_covered_cells = self.cover(true_poses, ids)
        else:
            self.last_covered_cells = np.zeros(self.cfg.n_robots, dtype=np.int64)
        if not ids.size:
            self.last_new_cells = np.zeros(self.cfg.n_robots, dtype=np.int64)
            return self.last_new_cells
        fix = readings.gps_mask  # only active robots get a fix
        if np.count_nonzero(fix):
            # DGPS altitude -> elevation in the map frame, as TerrainMap.update computes it.
            alt = np.where(fix, self._gps_offset + readings.gps_altitude, np.nan)
            nos = np.where(fix, readings.satellites, 0)
            if not whole:
                alt, nos = alt[ids], nos[ids]
        else:
            alt, nos = self._no_fix(ids.size)
        distance = np.add.reduce(readings.odometry[:, :, 0], 0)
        pos_var = est_cov[:, 0, 0] + est_cov[:, 1, 1]
        if not whole:
            distance, pitch = distance[ids], pitch[ids]
            est_mean, pos_var = est_mean[ids], pos_var[ids]
        distance *= self._dt_sub
        # The env built these arrays itself (float, right shapes): skip update's checks.
        cells = self.map.update_prepared(ids, est_mean, pos_var, pitch, alt, nos, distance)
        if whole:
            new = cells
        else:
            new = np.zeros(self.cfg.n_robots, dtype=np.int64)
            new[ids] = cells
        self.last_new_cells = new
        return new

    def _active_ids(self, active: np.ndarray) -> np.ndarray:
        """Indices of the active robots, read-only and cached per pattern (so the map
        checks them once)."""
        key = active.tobytes()
        ids = self._ids_cache.get(key)
        if ids is None:
            ids = np.flatnonzero(active)
            ids.flags.writeable = False
            if len(self._ids_cache) > 64:
                self._ids_cache.clear()
            self._ids_cache[key] = ids
        return ids

    def _no_fix(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Altitudes (NaN) and satellite counts (0) of ``k`` robots without a fix (read-only)."""
        arrays = self._no_fix_cache.get(k)
        if arrays is None:
            arrays = (np.full(k, np.nan), np.zeros(k))
            for arr in arrays:
                arr.flags.writeable = False
            self._no_fix_cache[k] = arrays
        return arrays

    def _on_merge(
        self, cells: np.ndarray, before: np.ndarray, after: np.ndarray, was_mapped: np.ndarray
    ) -> None:
        """Keep the squared-error sum and the covered count up to date (``merge_listener``)."""
        if not cells.size:  # a merge that wrote nothing
            return
        truth = self._truth_flat[cells]
        err_after = after - truth
        err_before = before - truth
        err_before *= was_mapped
        self._sq_error += float(np.dot(err_after, err_after) - np.dot(err_before, err_before))
        self._covered += int(np.count_nonzero(self._drivable_flat[cells] > was_mapped))

    def coverage(self) -> float:
        """Fraction of drivable cells that hold a measured elevation."""
        return self._covered / self._n_drivable

    def map_rmse(self) -> float:
        """RMSE (m) of the mapped cells against the true height field; NaN when none mapped.

        Kept as a running sum over merges (equal to ``TerrainMap.rmse`` up to rounding).
        """
        if self.map.n_mapped == 0:
            return float("nan")
        return math.sqrt(max(self._sq_error, 0.0) / self.map.n_mapped)

    def patches(self, est_mean: np.ndarray, size_cells: int) -> np.ndarray:
        """Egocentric patches ``(n, 3, S, S)`` around the estimated poses.

        Channels: elevation relative to the robot's own elevation estimate
        (0 where unmapped), mapped mask, object-of-interest mask.
        """
        ref, _ = self.map.robot_elevation()
        return self.map.local_patch(est_mean, size_cells, reference=ref)
