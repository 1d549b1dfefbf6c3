"""The cells of :class:`~estimators.terrain_map.TerrainMap`: grid geometry, stored layers, views.

:class:`TerrainGrid` maps world points to cells (``i`` along X, ``j`` along Y,
``indexing="ij"``, flat index ``i * ny + j``), holds the team map's per-cell layers
(elevation, confidence = inverse variance with 0 = unmapped, objects of interest) and
derives everything read from them: masks, coverage, RMSE against a true height field,
the gap-filled map, the paper's terrain matrix and egocentric patches.
:class:`~estimators.terrain_map.TerrainMap` adds what writes the layers (the robots'
elevation filters, local maps and merging); :func:`keep_best` is the merge rule
(Sec. 5.5 of Madhavan et al.: a sample replaces a cell's value when it is more confident).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import griddata
from scipy.spatial import QhullError


def float_vector(name: str, value: np.ndarray | float, n: int) -> np.ndarray:
    """``value`` as a float vector of length ``n`` (scalars broadcast); ValueError naming
    ``name`` for any other shape."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr


class TerrainGrid:
    """A ``size`` metres grid of square ``resolution`` cells whose lower-left corner is
    at world ``origin``, with the team map's layers and their views.

    Attributes:
        shape: ``(nx, ny)`` cells.
        resolution: cell edge length in metres.
        origin: world coordinates ``(x0, y0)`` of the grid's lower-left corner.
        objects: ``(x, y, radius)`` of every :meth:`mark_object` call.
    """

    def __init__(
        self, size: tuple[float, float], resolution: float, origin: tuple[float, float]
    ) -> None:
        if not np.isfinite(resolution) or resolution <= 0:
            raise ValueError(f"resolution must be > 0, got {resolution!r}")
        width, height = (float(s) for s in size)
        if not (width > 0 and height > 0):
            raise ValueError(f"size must be positive, got {size!r}")
        self.resolution = float(resolution)
        self.origin = (float(origin[0]), float(origin[1]))
        nx = int(np.ceil(width / resolution - 1e-9))
        ny = int(np.ceil(height / resolution - 1e-9))
        self.shape = (nx, ny)
        # The same as arrays, made once for the per-step cell lookups (None: origin at 0).
        self._shape_xy = np.array(self.shape, dtype=float)
        self._min_dim = float(min(self.shape))
        self._origin_xy = None if self.origin == (0.0, 0.0) else np.array(self.origin)
        self._origin_flat = np.zeros(0) if self._origin_xy is None else self._origin_xy.copy()
        self._n_cells = self.shape[0] * self.shape[1]
        self.clear_layers()

    def clear_layers(self) -> None:
        """Empty the stored layers: every cell unmapped, no object marked."""
        self._elev = np.zeros(self._n_cells)
        self._conf = np.zeros(self._n_cells)  # 0 = unmapped
        self._objects = np.zeros(self._n_cells, dtype=bool)
        self.objects: list[tuple[float, float, float]] = []

    # ------------------------------------------------------------------ views

    def cell_centers(self) -> tuple[np.ndarray, np.ndarray]:
        """World ``(X, Y)`` of every cell centre, each of shape :attr:`shape` (``indexing='ij'``).

        Evaluate the true height field there to get the grid
        :meth:`~estimators.terrain_map.TerrainMap.rmse` expects.
        """
        xs = self.origin[0] + (np.arange(self.shape[0]) + 0.5) * self.resolution
        ys = self.origin[1] + (np.arange(self.shape[1]) + 0.5) * self.resolution
        return np.meshgrid(xs, ys, indexing="ij")

    def world_to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices ``(i, j)`` of world points ``(..., 2)`` and a mask of those inside."""
        xy = np.asarray(xy, dtype=float)
        i = np.floor((xy[..., 0] - self.origin[0]) / self.resolution)
        j = np.floor((xy[..., 1] - self.origin[1]) / self.resolution)
        inside = (i >= 0) & (i < self.shape[0]) & (j >= 0) & (j < self.shape[1])
        inside &= np.isfinite(i) & np.isfinite(j)
        i = np.where(inside, i, 0).astype(np.intp)
        j = np.where(inside, j, 0).astype(np.intp)
        return i, j, inside

    def _flat_index(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`flat_index_xy` of world coordinates ``x``, ``y`` of any (equal) shape."""
        flat, inside = self.flat_index_xy(np.stack([np.ravel(x), np.ravel(y)], 1))
        return flat.reshape(np.shape(x)), inside.reshape(np.shape(x))

    def flat_index_xy(
        self, xy: np.ndarray, all_inside: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Flat cell indices of finite world points ``(k, 2)`` and the mask of those inside
        (the indices of points outside are meaningless).

        With ``all_inside=True`` the mask is None when every point is inside (two
        reductions instead of the elementwise mask).
        """
        f = (xy - self._origin_xy if self._origin_xy is not None else xy) * (1.0 / self.resolution)
        cell = f.astype(np.intp)
        flat = cell[:, 0] * self.shape[1]
        flat += cell[:, 1]
        if (
            all_inside
            and np.minimum.reduce(f, None) >= 0.0
            and np.maximum.reduce(f, None) < self._min_dim
        ):
            return flat, None
        # Negative values truncate towards 0, so test the floats.
        ok = f >= 0
        ok &= f < self._shape_xy
        return flat, ok[:, 0] & ok[:, 1]

    @property
    def elevation(self) -> np.ndarray:
        """Mapped elevations, shape :attr:`shape`; NaN where unmapped (a copy)."""
        out = np.where(self._conf > 0, self._elev, np.nan)
        return out.reshape(self.shape)

    @property
    def confidence(self) -> np.ndarray:
        """Confidence (inverse variance) of each cell's value; 0 where unmapped (a copy)."""
        return self._conf.reshape(self.shape).copy()

    @property
    def mapped(self) -> np.ndarray:
        """Boolean grid of cells holding a measured elevation."""
        return (self._conf > 0).reshape(self.shape)

    @property
    def object_mask(self) -> np.ndarray:
        """Boolean grid of cells marked as objects of interest."""
        return self._objects.reshape(self.shape).copy()

    def mark_object(self, x: float, y: float, radius: float = 0.0) -> int:
        """Mark an object of interest at world ``(x, y)`` (its estimated position).

        Every cell whose centre lies within ``radius`` of the point is marked,
        and always the cell containing the point. Returns the number of cells
        newly marked (0 if the point lies outside the grid and no cell is hit).
        """
        if not (np.isfinite(x) and np.isfinite(y)):
            raise ValueError(f"object position must be finite, got ({x!r}, {y!r})")
        if not np.isfinite(radius) or radius < 0:
            raise ValueError(f"radius must be finite and >= 0, got {radius!r}")
        xc, yc = self.cell_centers()
        hit = ((xc - x) ** 2 + (yc - y) ** 2 <= radius * radius).ravel()
        i, j, inside = self.world_to_cell(np.array([x, y]))
        if inside:
            hit[int(i) * self.shape[1] + int(j)] = True
        new = int(np.count_nonzero(hit & ~self._objects))
        self._objects |= hit
        self.objects.append((float(x), float(y), float(radius)))
        return new

    def coverage(self, drivable_mask: np.ndarray | None = None) -> float:
        """Fraction of drivable cells mapped (all cells when no mask is given)."""
        mapped = self._conf > 0
        if drivable_mask is None:
            return float(np.count_nonzero(mapped)) / self._n_cells
        mask = np.asarray(drivable_mask, dtype=bool)
        if mask.shape != self.shape:
            raise ValueError(f"drivable_mask must have shape {self.shape}, got {mask.shape}")
        total = np.count_nonzero(mask)
        if total == 0:
            raise ValueError("drivable_mask has no drivable cell")
        return float(np.count_nonzero(mapped & mask.ravel())) / total

    def rmse(self, true_height: np.ndarray, use_filled: bool = False) -> float:
        """RMSE of mapped elevation vs the true height grid over mapped cells.

        ``true_height`` is the true height field at :meth:`cell_centers`, in the
        map frame (``datum`` = its value at the base station). With
        ``use_filled`` the cubic gap-filled map is scored over every cell it
        defines. NaN when no cell is mapped.
        """
        truth = np.asarray(true_height, dtype=float)
        if truth.shape != self.shape:
            raise ValueError(f"true_height must have shape {self.shape}, got {truth.shape}")
        est = self.filled() if use_filled else self.elevation
        ok = np.isfinite(est)
        if not ok.any():
            return float("nan")
        err = est[ok] - truth[ok]
        return float(np.sqrt(np.mean(err * err)))

    def filled(self, method: str = "cubic") -> np.ndarray:
        """The map with gaps filled by interpolation (``scipy.interpolate.griddata``).

        Measured cells keep their values; unmapped cells inside the convex hull
        of the measured ones are interpolated (``method`` = ``'cubic'``,
        ``'linear'`` or ``'nearest'``); others stay NaN. When the measured cells
        are too few or collinear for a triangulation, gaps stay NaN.
        """
        return self.fill_gaps(self.elevation, method)

    def terrain_matrix(self, object_value: float = 1e3) -> np.ndarray:
        """The paper's Eq. 5: elevation where explored, 0 where not, ``object_value`` at objects."""
        t = np.where(self._conf > 0, self._elev, 0.0)
        t[self._objects] = object_value
        return t.reshape(self.shape)

    def local_patch(
        self, pose: np.ndarray, size_cells: int, reference: np.ndarray | float | None = None
    ) -> np.ndarray:
        """Egocentric map patch(es) around ``pose`` for observations.

        Args:
            pose: ``(3,)`` or ``(N, 3)`` estimated poses.
            size_cells: patch edge in cells (odd keeps the robot on the centre cell).
            reference: elevation(s) subtracted from mapped values, e.g. the
                robot's own estimate from :meth:`robot_elevation`.

        Returns:
            ``(3, S, S)`` (or ``(N, 3, S, S)``) float32 channels: elevation
            (minus ``reference``; 0 where unmapped), mapped mask, object mask.
            Axis 1 runs along the robot's forward axis, axis 2 along its left
            axis, both ascending, sampled every ``resolution`` metres; cells
            outside the grid read as unmapped.
        """
        if int(size_cells) != size_cells or size_cells < 1:
            raise ValueError(f"size_cells must be a positive integer, got {size_cells!r}")
        poses = np.asarray(pose, dtype=float)
        single = poses.ndim == 1
        poses = np.atleast_2d(poses)
        if poses.ndim != 2 or poses.shape[1] != 3 or not np.all(np.isfinite(poses)):
            raise ValueError(f"pose must be finite with shape (3,) or (N, 3), got {pose!r}")
        n, size = poses.shape[0], int(size_cells)
        k = (np.arange(size) - (size - 1) / 2.0) * self.resolution
        u, v = np.meshgrid(k, k, indexing="ij")
        c, s = np.cos(poses[:, 2])[:, None, None], np.sin(poses[:, 2])[:, None, None]
        wx = poses[:, 0, None, None] + c * u - s * v
        wy = poses[:, 1, None, None] + s * u + c * v
        flat, inside = self._flat_index(wx, wy)
        flat[~inside] = 0
        known = inside & (self._conf[flat] > 0)
        ref = 0.0 if reference is None else float_vector("reference", reference, n)[:, None, None]
        out = np.empty((n, 3, size, size), dtype=np.float32)
        out[:, 0] = np.where(known, self._elev[flat] - ref, 0.0)
        out[:, 1] = known
        out[:, 2] = inside & self._objects[flat]
        return out[0] if single else out

    def fill_gaps(self, values: np.ndarray, method: str = "cubic") -> np.ndarray:
        """``values`` (shape :attr:`shape`, NaN = unknown) with gaps filled by interpolation
        (``scipy.interpolate.griddata`` over the cell centres; modified in place, returned).

        Cells inside the convex hull of the known ones are interpolated (``method`` =
        ``'cubic'``, ``'linear'`` or ``'nearest'``); others stay NaN. When the known cells
        are too few or collinear for a triangulation, gaps stay NaN.
        """
        if method not in ("cubic", "linear", "nearest"):
            raise ValueError(f"method must be 'cubic', 'linear' or 'nearest', got {method!r}")
        known = np.isfinite(values)
        if known.all() or np.count_nonzero(known) < 3:
            return values
        xc, yc = self.cell_centers()
        pts = np.stack([xc[known], yc[known]], axis=1)
        try:
            values[~known] = griddata(pts, values[known], (xc[~known], yc[~known]), method=method)
        except (QhullError, ValueError):
            pass
        return values


def best_per_cell(flat: np.ndarray, conf: np.ndarray) -> np.ndarray | None:
    """Indices of the highest-confidence sample of each distinct cell in ``flat``.

    None when no cell is sampled twice (every sample is its cell's best).
    """
    lst = flat.tolist()
    if len(set(lst)) == len(lst):
        return None
    order = np.lexsort((conf, flat))
    f = flat[order]
    last = np.empty(f.size, dtype=bool)
    last[:-1] = f[1:] != f[:-1]
    last[-1] = True
    return order[last]


def keep_best(
    elev: np.ndarray,
    confs: np.ndarray,
    flat: np.ndarray,
    vals: np.ndarray,
    conf: np.ndarray,
    stored: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Write samples (cells ``flat``, values ``vals``, confidences ``conf``) into the flat
    cell arrays ``elev``, ``confs`` where they beat the stored confidence.

    ``stored`` is ``confs[flat]`` when the caller has looked it up already. Of several
    samples of one cell only the most confident may win. Returns the winners' indices
    into the samples, their cells, the values written there and the values they
    replaced; None when no sample wins (nothing is written).
    """
    if stored is None:
        stored = confs[flat]
    win = conf > stored
    if not np.count_nonzero(win):  # the usual case on ground mapped before
        return None
    best = best_per_cell(flat, conf)
    # Every sample is its cell's best, or only each cell's best may win.
    idx = win.nonzero()[0] if best is None else best[win[best]]
    fw = flat[idx]
    won = vals[idx]
    replaced = elev[fw]
    elev[fw] = won
    confs[fw] = conf[idx]
    return idx, fw, won, replaced
