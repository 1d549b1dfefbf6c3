"""Team terrain map from elevation samples (Madhavan, Fregene, Parker, Sec. 5.4-5.5).

What the map stores
-------------------
The terrain matrix ``T[i, j]`` covers a global grid: ``i`` indexes X, ``j``
indexes Y (``indexing="ij"``), cell ``(i, j)`` spans
``[x0 + i*res, x0 + (i+1)*res) x [y0 + j*res, y0 + (j+1)*res)``. Each cell
holds an *elevation* in the map frame (the base station's elevation plus the
altitude above it, see :mod:`estimators.terrain_fusion`), not the paper's
per-step increment, so the map can be compared with a true height field
(:meth:`TerrainMap.rmse`). Unexplored cells hold 0 in :meth:`terrain_matrix`
(the paper's Eq. 5) and NaN in :attr:`TerrainMap.elevation`.

How a sample is made and registered
-----------------------------------
Each robot integrates its own elevation along its path with
:func:`~estimators.terrain_fusion.fuse_elevation` (inclinometer pitch times
distance driven, blended with DGPS altitude by the paper's satellite-count
weights). The sample is registered at the robot's *estimated* pose, so
localization error corrupts the map as on a real robot. With a footprint
radius, the cells under the robot receive the elevation extrapolated along
the heading with the measured pitch.

Confidence and merging
----------------------
Every sample carries a confidence ``1 / var``, where ``var`` is the fused
elevation variance (small with many satellites in view) plus the elevation
error that the position uncertainty causes, ``slope^2 * (P_xx + P_yy)`` (the
analogue of the paper's range variance: the less sure the robot is of where it
is, the less sure it is of which cell it measured), plus a footprint term
growing with the distance from the robot's centre. When a cell is covered
again, by the same or by another robot, the value with the higher confidence
is kept (Sec. 5.5).

Samples first go to the robot's local map (its current motion segment
``P1 -> P2``). With ``merge_every_step=True`` (default) each update merges
straight into the team map, which is what a per-step coverage reward needs;
with ``False`` the local maps accumulate until :meth:`TerrainMap.end_segment`
merges them, as in the paper. Gaps are filled by cubic interpolation only in
the derived view :meth:`TerrainMap.filled`; coverage counts measured cells.
Objects of interest live in their own layer (:meth:`TerrainMap.mark_object`)
and appear with a large value in :meth:`TerrainMap.terrain_matrix`.

Use, once per mapping step, for all robots at once::

    tmap = TerrainMap(n_robots, size=(w, h), resolution=0.5, datum=h_base)
    tmap.reset(initial_elevation=start_heights)      # at episode start
    new = tmap.update(ids, est_poses, pose_covs, pitch, gps_alt, nos,
                      distance, base_alt)            # (N,) newly mapped cells
    patches = tmap.local_patch(est_poses, 11)        # (N, 3, 11, 11) observations
    tmap.coverage(drivable), tmap.rmse(true_heights) # metrics

:meth:`TerrainMap.update` costs a few tens of numpy operations whatever the
number of robots (about 70 us for 5 robots on a slow 2-core box);
:meth:`TerrainMap.update_prepared` is the same update for a caller that prepares
its arrays itself (the env, every step). :meth:`TerrainMap.filled` runs a
triangulation and is meant for evaluation and rendering, not for every step.

The grid geometry, the stored layers and every view of them (masks, metrics,
patches) come from the base class :class:`~estimators.terrain_grid.TerrainGrid`;
this module holds what writes the layers.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from estimators._map_kernels import footprint_samples, fuse_without_fix
from estimators.terrain_fusion import fuse_elevation_tangents
from estimators.terrain_grid import TerrainGrid, float_vector, keep_best

# What a merge that writes nothing hands the listener: no cells, before/after values
# or was-mapped flags (shared, so read-only).
_NO_CELLS = (np.zeros(0, dtype=np.intp), np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool))
for _arr in _NO_CELLS:
    _arr.flags.writeable = False


class TerrainMap(TerrainGrid):
    """Team elevation map with per-robot elevation filters, local maps and confidence merging.

    Args:
        n_robots: number of robots; robot ids are ``0 .. n_robots - 1``.
        size: ``(width, height)`` of the mapped area in metres.
        resolution: cell edge length in metres.
        origin: world coordinates ``(x0, y0)`` of the grid's lower-left corner.
        datum: elevation of the DGPS base station in the map frame (the true
            height field's value there, when comparing with it).
        pitch_std: inclinometer noise standard deviation (rad).
        gps_alt_std: DGPS altitude noise standard deviation at 10 satellites (m).
        footprint_radius: cells whose centre lies within this distance (m) of
            the robot are written by one sample; 0 writes the robot's cell only.
        slope_floor: minimum terrain slope assumed when turning position
            variance into elevation variance (also used for the footprint).
        merge_every_step: merge local maps into the team map at every update.
        min_var: variance floor, so confidences stay finite.
        weights: ``"paper"`` (satellite-count fusion weights) or ``"kalman"``
            (variance-optimal gain); see :func:`~estimators.terrain_fusion.fuse_elevation`.

    Attributes:
        merge_listener: optional ``f(cells, before, after, was_mapped)`` called
            after every merge into the team map with the flat indices of the
            cells written, their elevations before and after, and whether they
            were mapped before (lets a caller keep running statistics of the map).
    """

    def __init__(
        self,
        n_robots: int,
        size: tuple[float, float],
        resolution: float = 0.5,
        origin: tuple[float, float] = (0.0, 0.0),
        datum: float = 0.0,
        pitch_std: float = np.deg2rad(0.5),
        gps_alt_std: float = 0.3,
        footprint_radius: float = 0.0,
        slope_floor: float = 0.05,
        merge_every_step: bool = True,
        min_var: float = 1e-6,
        weights: str = "paper",
    ) -> None:
        if int(n_robots) != n_robots or n_robots < 1:
            raise ValueError(f"n_robots must be a positive integer, got {n_robots!r}")
        self.merge_listener: Callable[..., None] | None = None
        super().__init__(size, resolution, origin)
        for name, val in (
            ("pitch_std", pitch_std),
            ("gps_alt_std", gps_alt_std),
            ("footprint_radius", footprint_radius),
            ("slope_floor", slope_floor),
        ):
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {val!r}")
        if not min_var > 0:
            raise ValueError(f"min_var must be > 0, got {min_var!r}")
        if weights not in ("paper", "kalman"):
            raise ValueError(f"weights must be 'paper' or 'kalman', got {weights!r}")
        self.weights = weights
        self.n_robots = int(n_robots)
        self.datum = float(datum)
        self.pitch_std = float(pitch_std)
        self.gps_alt_std = float(gps_alt_std)
        self.slope_floor = float(slope_floor)
        self.merge_every_step = bool(merge_every_step)
        self.min_var = float(min_var)
        self._footprint = self._make_footprint(float(footprint_radius))
        # Extra variance of footprint cells: unknown cross-slope over their offset.
        self._footprint_var = (self._footprint**2).sum(axis=1) * self.slope_floor**2
        self._fp_x, self._fp_y = self._footprint[:, 0].copy(), self._footprint[:, 1].copy()
        self._valid_ids: np.ndarray | None = None  # an id array already checked ...
        self._valid_bytes = b""  # ... and its contents then (a cache hit needs both)
        self._owner = np.zeros(0, dtype=np.intp)  # its samples' robot ids (footprint repeat)
        self._valid_whole = False  # ... and whether it is every robot in id order
        self._pitch_key = b""  # pitch values whose tangent terms _pitch_cache holds
        self._pitch_cache: tuple[np.ndarray, ...] = ()
        self.reset()

    # ------------------------------------------------------------------ setup
    def _make_footprint(self, radius: float) -> np.ndarray:
        """Offsets ``(K, 2)`` in metres of the cells a sample writes, centre first."""
        n = int(np.floor(radius / self.resolution))
        k = np.arange(-n, n + 1) * self.resolution
        ox, oy = np.meshgrid(k, k, indexing="ij")
        off = np.stack([ox.ravel(), oy.ravel()], axis=1)
        off = off[np.hypot(off[:, 0], off[:, 1]) <= radius + 1e-9]
        order = np.argsort(np.hypot(off[:, 0], off[:, 1]), kind="stable")
        return off[order]

    def reset(
        self,
        initial_elevation: np.ndarray | float | None = None,
        initial_var: np.ndarray | float = 0.0,
    ) -> None:
        """Clear the maps and objects; set every robot's elevation estimate.

        ``initial_elevation`` defaults to ``datum`` (the paper assumes the
        robots start at the base station's altitude, ``Zg = Zg0``).
        """
        elev0 = self.datum if initial_elevation is None else initial_elevation
        self._robot_elev = float_vector("initial_elevation", elev0, self.n_robots).copy()
        self._robot_var = float_vector("initial_var", initial_var, self.n_robots).copy()
        if np.any(self._robot_var < 0):
            raise ValueError(f"initial_var must be >= 0, got {initial_var!r}")
        self.clear_layers()
        local_cells = 0 if self.merge_every_step else self._n_cells
        self._local_elev = np.zeros((self.n_robots, local_cells))
        self._local_conf = np.zeros((self.n_robots, local_cells))
        self.n_mapped = 0
        self.newly_mapped_cells = 0

    def set_robot_elevation(
        self,
        robot_ids: np.ndarray | int,
        elevation: np.ndarray | float,
        var: np.ndarray | float = 0.0,
    ) -> None:
        """Overwrite the elevation estimate of some robots (e.g. a known start height)."""
        ids = self._ids(robot_ids)
        self._robot_elev[ids] = float_vector("elevation", elevation, ids.size)
        v = float_vector("var", var, ids.size)
        if np.any(v < 0):
            raise ValueError(f"var must be >= 0, got {var!r}")
        self._robot_var[ids] = v

    # ------------------------------------------------------------- properties
    @property
    def footprint(self) -> np.ndarray:
        """Offsets ``(K, 2)`` in metres from a robot's position of the cells one sample
        writes, centre first (``K = 1`` without a ``footprint_radius``; a copy)."""
        return self._footprint.copy()

    def robot_elevation(
        self, robot_ids: np.ndarray | int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Current elevation estimates and variances of ``robot_ids`` (all by default)."""
        ids = np.arange(self.n_robots) if robot_ids is None else self._ids(robot_ids)
        return self._robot_elev[ids].copy(), self._robot_var[ids].copy()

    # ---------------------------------------------------------------- update
    def _ids(self, robot_ids: np.ndarray | int) -> np.ndarray:
        if robot_ids is self._valid_ids and robot_ids.tobytes() == self._valid_bytes:
            return robot_ids  # checked before, unchanged since
        ids = np.asarray(robot_ids)
        if ids.ndim == 0:
            ids = ids.reshape(1)
        if ids.ndim != 1 or ids.dtype.kind not in "iu":
            raise ValueError(f"robot_ids must be a 1-D array of ints, got {robot_ids!r}")
        lst = ids.tolist()
        if lst and (min(lst) < 0 or max(lst) >= self.n_robots):
            raise ValueError(f"robot_ids must lie in [0, {self.n_robots}), got {robot_ids!r}")
        if len(set(lst)) != len(lst):
            raise ValueError(f"robot_ids must not repeat, got {robot_ids!r}")
        ids = ids.astype(np.intp, copy=False)
        if ids is robot_ids:
            self._valid_ids, self._valid_bytes = ids, ids.tobytes()
            self._owner = np.repeat(ids, self._footprint.shape[0])
            self._valid_whole = lst == list(range(self.n_robots))
        return ids

    def update(
        self,
        robot_ids: np.ndarray,
        est_poses: np.ndarray,
        pose_covs: np.ndarray,
        pitch: np.ndarray,
        gps_alt: np.ndarray,
        nos: np.ndarray,
        distance: np.ndarray,
        base_alt: float,
    ) -> np.ndarray:
        """Fuse one elevation sample per robot and register it at the estimated pose.

        Args:
            robot_ids: ``(N,)`` ints, distinct.
            est_poses: ``(N, 3)`` estimated ``(x, y, heading)``.
            pose_covs: ``(N, 3, 3)`` or ``(N, 2, 2)`` pose covariances (only the
                position block is used).
            pitch: ``(N,)`` inclinometer pitch (rad, nose up positive).
            gps_alt: ``(N,)`` DGPS altitude ``Zg``; NaN (or None in a list) = no fix.
            nos: ``(N,)`` satellites in view (0 = no fix).
            distance: ``(N,)`` signed horizontal distance driven along the heading
                since the robot's previous sample (negative when reversing).
            base_alt: DGPS altitude of the base station ``Zg0``.

        Returns:
            ``(N,)`` ints: cells each robot newly added to the team map (all zero
            when ``merge_every_step`` is False). The total is also in
            :attr:`newly_mapped_cells`. Samples outside the grid are dropped.
        """
        ids = self._ids(robot_ids)
        n = ids.size
        poses = np.asarray(est_poses, dtype=float)
        if poses.shape != (n, 3):
            raise ValueError(f"est_poses must have shape ({n}, 3), got {poses.shape}")
        covs = np.asarray(pose_covs, dtype=float)
        if covs.ndim != 3 or covs.shape[0] != n or covs.shape[1:] not in ((3, 3), (2, 2)):
            raise ValueError(
                f"pose_covs must have shape ({n}, 3, 3) or ({n}, 2, 2), got {covs.shape}"
            )
        pitch = float_vector("pitch", pitch, n)
        gps_alt = float_vector("gps_alt", gps_alt, n)
        nos = float_vector("nos", nos, n)
        distance = float_vector("distance", distance, n)
        pos_var = covs[:, 0, 0] + covs[:, 1, 1]
        for name, value in (("est_poses", poses), ("pose_covs", pos_var), ("pitch", pitch),
                            ("distance", distance)):
            if not np.isfinite(value).all():  # named here, before any arithmetic warns
                raise ValueError(f"{name} must be finite, got {value!r}")
        gps_elev = (self.datum - float(base_alt)) + gps_alt
        return self.update_prepared(ids, poses, pos_var, pitch, gps_elev, nos, distance)

    def update_prepared(
        self,
        ids: np.ndarray,
        poses: np.ndarray,
        pos_var: np.ndarray,
        pitch: np.ndarray,
        gps_elev: np.ndarray,
        nos: np.ndarray,
        distance: np.ndarray,
    ) -> np.ndarray:
        """:meth:`update` (its one implementation) on arrays the caller has prepared.

        For callers that built the arrays themselves (the env's
        :class:`~coop_loc_env.mapping.TeamMapper`, every step): ``ids`` distinct valid
        robot ids (an int array; the map remembers the last one it checked, so passing
        the same read-only array skips the check), ``poses`` ``(N, 3)`` floats,
        ``pos_var`` the position variance ``P_xx + P_yy`` (what :meth:`update` takes from
        ``pose_covs``), ``gps_elev`` the DGPS elevation in the map frame (``datum + Zg -
        Zg0``, what :meth:`update` makes of ``gps_alt`` and ``base_alt``; NaN = no fix)
        and the other arguments ``(N,)`` float arrays as in :meth:`update`. Returns what
        :meth:`update` returns. Non-finite poses, variances, pitch or distance are still
        rejected before anything is written.
        """
        n = ids.size
        # Every robot in id order: its rows as views, its counts as the merge returns them.
        whole = ids is self._valid_ids and self._valid_whole
        rows = slice(None) if whole else ids
        tan_p, tan2, slope2 = self._pitch_terms(pitch)
        several = self._footprint.shape[0] > 1
        if self.merge_every_step and several and not np.count_nonzero(nos):
            # The usual step: one compiled pass (None: the numpy path below decides).
            elev, var, var_s = np.empty(n), np.empty(n), np.empty(n)
            if fuse_without_fix(self._robot_elev[rows], self._robot_var[rows], distance, tan_p,
                                tan2, slope2, pos_var, self.pitch_std, self.min_var, poses,
                                elev, var, var_s):
                self._robot_elev[rows] = elev
                self._robot_var[rows] = var
                return self._sample_and_merge(ids, poses, elev, var_s, tan_p, whole)
        elev, var_s = self._fuse(rows, poses, pos_var, pitch, gps_elev, nos, distance,
                                 tan_p, tan2, slope2)
        if several and self.merge_every_step:
            return self._sample_and_merge(ids, poses, elev, var_s, tan_p, whole)
        return self._register(ids, poses, elev, var_s, tan_p, whole)

    def _fuse(
        self, rows: np.ndarray | slice, poses: np.ndarray, pos_var: np.ndarray,
        pitch: np.ndarray, gps_elev: np.ndarray, nos: np.ndarray, distance: np.ndarray,
        tan_p: np.ndarray, tan2: np.ndarray, slope2: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The elevation filters' step of robots ``rows`` (stored) and the samples'
        variances, after checking that every input was finite; returns ``(elev, var_s)``."""
        elev, var = fuse_elevation_tangents(
            self._robot_elev[rows],
            self._robot_var[rows],
            distance,
            tan_p,
            tan2,
            gps_elev,
            nos if np.count_nonzero(nos) else None,  # no satellites anywhere: no fix at all
            self.pitch_std,
            self.gps_alt_std,
            self.weights,
        )
        # Sample variance: elevation + position error seen through the slope.
        var_s = slope2 * pos_var
        var_s += var
        np.maximum(var_s, self.min_var, out=var_s)
        # One finiteness check covers poses, pitch, distance and covariances: a NaN or an
        # infinity in elev or var_s (> 0) makes the sum NaN or infinite.
        if not math.isfinite(np.add.reduce(elev + var_s) + np.add.reduce(poses, None)):
            raise ValueError(
                f"est_poses, pose_covs, pitch and distance must be finite, got {poses!r}, "
                f"{pos_var!r}, {pitch!r}, {distance!r}"
            )
        self._robot_elev[rows] = elev
        self._robot_var[rows] = var
        return elev, var_s

    def _register(
        self, ids: np.ndarray, poses: np.ndarray, elev: np.ndarray, var_s: np.ndarray,
        tan_p: np.ndarray, whole: bool,
    ) -> np.ndarray:
        """The end of :meth:`update_prepared` for a one-cell footprint, or for local maps
        merged at :meth:`end_segment`: the samples and their cells in numpy, then the
        merge (or the local maps' keep-best write)."""
        fp = self._footprint
        if fp.shape[0] == 1:
            xy = poses[:, :2]
            vals, conf, owner = elev, var_s, ids
        else:
            xy = (poses[:, None, :2] + fp).reshape(-1, 2)
            heading = poses[:, 2]  # 1-D: the trigonometry runs faster than on a column
            # elev + tan(pitch) * (offset along the heading), built in place.
            vals = np.cos(heading)[:, None] * self._fp_x
            vals += np.sin(heading)[:, None] * self._fp_y
            vals *= tan_p[:, None]
            vals += elev[:, None]
            vals = vals.reshape(-1)
            conf = (var_s[:, None] + self._footprint_var).reshape(-1)
            owner = self._owner if ids is self._valid_ids else np.repeat(ids, fp.shape[0])
        np.divide(1.0, conf, out=conf)  # a fresh array: confidence = 1 / variance
        flat, inside = self.flat_index_xy(xy, all_inside=True)
        if inside is not None and np.count_nonzero(inside) < inside.size:
            flat, vals, conf, owner = flat[inside], vals[inside], conf[inside], owner[inside]

        if self.merge_every_step:  # the local map is this step's samples: merge them now
            new = self._merge(flat, vals, conf, owner)
            return new if whole else new[ids]
        # Register into the local (segment) maps, keeping the best sample per cell.
        keep_best(
            self._local_elev.reshape(-1),
            self._local_conf.reshape(-1),
            owner * self._n_cells + flat,
            vals,
            conf,
        )
        self.newly_mapped_cells = 0
        return np.zeros(ids.size, dtype=np.int64)

    def _sample_and_merge(
        self, ids: np.ndarray, poses: np.ndarray, elev: np.ndarray, var_s: np.ndarray,
        tan_p: np.ndarray, whole: bool,
    ) -> np.ndarray:
        """The end of :meth:`update_prepared` for a footprint of several cells merged every step:
        the samples and their cells in one compiled pass
        (:func:`estimators._map_kernels.footprint_samples`), then :meth:`_merge` unless
        no sample beats its cell's stored confidence."""
        size = ids.size * self._footprint.shape[0]
        flat = np.empty(size, dtype=np.intp)
        vals, conf = np.empty(size), np.empty(size)
        owner = np.empty(size, dtype=np.intp)
        heading = poses[:, 2]
        m, win = footprint_samples(
            poses, elev, var_s, tan_p, np.cos(heading), np.sin(heading), self._footprint,
            self._footprint_var, self._origin_flat, 1.0 / self.resolution, self.shape[0],
            self.shape[1], ids, self._conf, flat, vals, conf, owner,
        )
        if win:
            if m < size:
                flat, vals, conf, owner = flat[:m], vals[:m], conf[:m], owner[:m]
            new = self._merge(flat, vals, conf, owner)
            return new if whole else new[ids]
        # No sample wins (the usual case on ground mapped before): what _merge does then.
        self.newly_mapped_cells = 0
        if self.merge_listener is not None:
            self.merge_listener(*_NO_CELLS)
        return np.zeros(self.n_robots if whole else ids.size, dtype=np.int64)

    def _pitch_terms(self, pitch: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``tan(pitch)``, its square and the squared slope ``max(tan^2, slope_floor^2)`` of
        float64 pitches (read-only), kept while the pitch values repeat (the inclinometer
        reads at 1 Hz and the env latches its pitch in between)."""
        key = pitch.tobytes()
        if key != self._pitch_key:
            tan_p = np.tan(pitch)
            tan2 = tan_p * tan_p
            terms = tan_p, tan2, np.maximum(tan2, self.slope_floor**2)
            for arr in terms:
                arr.flags.writeable = False
            self._pitch_key, self._pitch_cache = key, terms
        return self._pitch_cache

    def _merge(
        self, flat: np.ndarray, vals: np.ndarray, conf: np.ndarray, owner: np.ndarray
    ) -> np.ndarray:
        """Merge samples into the team map; return newly mapped cells per robot id."""
        stored = self._conf[flat]
        kept = keep_best(self._elev, self._conf, flat, vals, conf, stored)
        if kept is None:
            self.newly_mapped_cells = 0
            if self.merge_listener is not None:
                self.merge_listener(*_NO_CELLS)
            return np.zeros(self.n_robots, dtype=np.int64)
        idx, cells, after, before = kept
        was_mapped = stored[idx] > 0
        if self.merge_listener is not None:
            self.merge_listener(cells, before, after, was_mapped)
        n_new = idx.size - np.count_nonzero(was_mapped)
        self.newly_mapped_cells = n_new
        if not n_new:
            return np.zeros(self.n_robots, dtype=np.int64)
        self.n_mapped += n_new
        return np.bincount(owner[idx[~was_mapped]], minlength=self.n_robots)

    def end_segment(self, robot_ids: np.ndarray | int | None = None) -> np.ndarray:
        """Merge the local maps of ``robot_ids`` (all by default) into the team map.

        Call it when a robot finishes a motion segment (reaches the next object
        of interest, Sec. 5.3). Each local map is cleared afterwards. Returns the
        cells each of those robots newly added to the team map, shape ``(N,)``.
        """
        ids = np.arange(self.n_robots) if robot_ids is None else self._ids(robot_ids)
        local = self._local_conf[ids]
        r, flat = np.nonzero(local > 0)
        owner = ids[r]
        newly = self._merge(flat, self._local_elev[owner, flat], local[r, flat], owner)
        self._local_conf[ids] = 0.0
        return newly[ids]

    def local_map(self, robot_id: int) -> np.ndarray:
        """The robot's current (unmerged) segment map, NaN where it has no sample.

        Always all NaN when ``merge_every_step`` is True (samples merge at once).
        """
        rid = int(self._ids(robot_id)[0])
        if self.merge_every_step:
            return np.full(self.shape, np.nan)
        m = np.where(self._local_conf[rid] > 0, self._local_elev[rid], np.nan)
        return m.reshape(self.shape)
