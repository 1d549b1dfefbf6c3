"""Occupancy grid maps: world <-> cell conversions, distance fields and ray casting.

Conventions
-----------
``occupied`` is a boolean array of shape ``(ny, nx)``; row ``iy`` covers world
``y`` in ``[oy + iy * res, oy + (iy + 1) * res)`` and column ``ix`` covers ``x``
in ``[ox + ix * res, ox + (ix + 1) * res)``, where ``(ox, oy)`` is ``origin``
(the world position of the lower-left corner of cell ``(0, 0)``). Everything
outside the grid is treated as occupied by the ray caster (the map's border is
a wall) and as "not free" by :meth:`OccupancyGrid.is_free`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy import ndimage

__all__ = ["OccupancyGrid"]


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """A 2D boolean occupancy grid with a metric resolution and origin.

    Parameters
    ----------
    occupied:
        ``(ny, nx)`` boolean array, ``True`` where a cell is an obstacle.
    resolution:
        Cell edge length in metres (> 0).
    origin:
        World ``(x, y)`` of the lower-left corner of cell ``(0, 0)``.
    """

    occupied: np.ndarray
    resolution: float
    origin: tuple[float, float] = (0.0, 0.0)
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        occ = np.asarray(self.occupied)
        if occ.ndim != 2 or occ.shape[0] < 1 or occ.shape[1] < 1:
            raise ValueError(f"occupied must be a non-empty 2D array, got shape {occ.shape}")
        if occ.dtype != bool:
            raise ValueError(f"occupied must be a bool array, got dtype {occ.dtype}")
        res = float(self.resolution)
        if not np.isfinite(res) or res <= 0.0:
            raise ValueError(f"resolution must be a positive finite number, got {self.resolution}")
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 2 or not all(np.isfinite(origin)):
            raise ValueError(f"origin must be two finite numbers, got {self.origin}")
        occ = occ.copy()
        occ.setflags(write=False)
        object.__setattr__(self, "occupied", occ)
        object.__setattr__(self, "resolution", res)
        object.__setattr__(self, "origin", origin)

    # ------------------------------------------------------------- construction
    @classmethod
    def from_shapes(
        cls,
        size: tuple[float, float],
        resolution: float,
        origin: tuple[float, float] = (0.0, 0.0),
        circles: list[tuple[tuple[float, float], float]] = (),
        segments: list[tuple[tuple[float, float], tuple[float, float], float]] = (),
        polygons: list[np.ndarray] = (),
        border: bool = True,
    ) -> OccupancyGrid:
        """Rasterize simple shapes into a grid covering ``size = (width, height)`` m.

        ``circles``: ``(center, radius)``; ``segments``: ``(a, b, half_width)``
        (thin walls: a cell is occupied when its centre is within
        ``max(half_width, resolution / sqrt(2))`` of the segment, so a wall
        never leaks between diagonal cells); ``polygons``: ``(V, 2)`` vertex
        arrays, filled (even-odd rule). ``border`` marks the outermost ring of
        cells (the world's boundary walls). A cell is occupied when its centre
        is inside a shape.
        """
        width, height = (float(v) for v in size)
        res = float(resolution)
        if not (width > 0 and height > 0 and np.isfinite(width) and np.isfinite(height)):
            raise ValueError(f"size must be two positive finite numbers, got {size}")
        if not (np.isfinite(res) and res > 0):
            raise ValueError(f"resolution must be a positive finite number, got {resolution}")
        nx, ny = int(np.ceil(width / res - 1e-9)), int(np.ceil(height / res - 1e-9))
        occ = np.zeros((ny, nx), dtype=bool)
        ox, oy = float(origin[0]), float(origin[1])
        xs = ox + (np.arange(nx) + 0.5) * res
        ys = oy + (np.arange(ny) + 0.5) * res

        def window(lo: np.ndarray, hi: np.ndarray) -> tuple[slice, slice]:
            i0 = int(np.clip(np.floor((lo[0] - ox) / res), 0, nx))
            i1 = int(np.clip(np.ceil((hi[0] - ox) / res) + 1, 0, nx))
            j0 = int(np.clip(np.floor((lo[1] - oy) / res), 0, ny))
            j1 = int(np.clip(np.ceil((hi[1] - oy) / res) + 1, 0, ny))
            return slice(j0, j1), slice(i0, i1)

        for center, radius in circles:
            c = np.asarray(center, dtype=float)
            if not (np.all(np.isfinite(c)) and radius > 0):
                raise ValueError(f"circle needs a finite center and radius > 0, got {center}, "
                                 f"{radius}")
            sy, sx = window(c - radius, c + radius)
            gx, gy = np.meshgrid(xs[sx], ys[sy])
            occ[sy, sx] |= (gx - c[0]) ** 2 + (gy - c[1]) ** 2 <= radius**2
        for a, b, half_width in segments:
            a = np.asarray(a, dtype=float)
            b = np.asarray(b, dtype=float)
            if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and half_width >= 0):
                raise ValueError(f"segment needs finite ends and half_width >= 0, got {a}, {b}, "
                                 f"{half_width}")
            reach = max(float(half_width), res / np.sqrt(2.0))
            sy, sx = window(np.minimum(a, b) - reach, np.maximum(a, b) + reach)
            gx, gy = np.meshgrid(xs[sx], ys[sy])
            d = b - a
            length2 = float(d @ d)
            t = 0.0 if length2 == 0 else np.clip(((gx - a[0]) * d[0] + (gy - a[1]) * d[1])
                                                 / length2, 0.0, 1.0)
            occ[sy, sx] |= (gx - a[0] - t * d[0]) ** 2 + (gy - a[1] - t * d[1]) ** 2 <= reach**2
        for verts in polygons:
            v = np.asarray(verts, dtype=float)
            if v.ndim != 2 or v.shape[0] < 3 or v.shape[1] != 2 or not np.all(np.isfinite(v)):
                raise ValueError(f"polygon needs (V >= 3, 2) finite vertices, got shape {v.shape}")
            sy, sx = window(v.min(axis=0), v.max(axis=0))
            gx, gy = np.meshgrid(xs[sx], ys[sy])
            inside = np.zeros(gx.shape, dtype=bool)
            for (x0, y0), (x1, y1) in zip(v, np.roll(v, -1, axis=0), strict=True):
                if y0 == y1:
                    continue
                crosses = (y0 > gy) != (y1 > gy)
                x_at = x0 + (gy - y0) * (x1 - x0) / (y1 - y0)
                inside ^= crosses & (gx < x_at)
            occ[sy, sx] |= inside
        if border:
            occ[0, :] = occ[-1, :] = True
            occ[:, 0] = occ[:, -1] = True
        return cls(occ, res, (ox, oy))

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        """``(ny, nx)``."""
        return self.occupied.shape

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """World extent ``(xmin, ymin, xmax, ymax)`` of the grid."""
        ny, nx = self.shape
        ox, oy = self.origin
        return ox, oy, ox + nx * self.resolution, oy + ny * self.resolution

    def world_to_cell(self, xy: np.ndarray) -> np.ndarray:
        """Integer cell indices ``(..., 2)`` as ``(ix, iy)`` of world points ``(..., 2)``.

        Points outside the grid get indices outside ``[0, nx) x [0, ny)``.
        """
        xy = np.asarray(xy, dtype=float)
        if xy.shape[-1] != 2:
            raise ValueError(f"points must have a trailing axis of 2, got shape {xy.shape}")
        return np.floor((xy - np.asarray(self.origin)) / self.resolution).astype(np.intp)

    def cell_to_world(self, cells: np.ndarray) -> np.ndarray:
        """World coordinates of the centres of cells ``(..., 2)`` given as ``(ix, iy)``."""
        cells = np.asarray(cells, dtype=float)
        if cells.shape[-1] != 2:
            raise ValueError(f"cells must have a trailing axis of 2, got shape {cells.shape}")
        return (cells + 0.5) * self.resolution + np.asarray(self.origin)

    def in_bounds(self, xy: np.ndarray) -> np.ndarray:
        """Boolean mask of world points ``(..., 2)`` that lie inside the grid."""
        c = self.world_to_cell(xy)
        ny, nx = self.shape
        return (c[..., 0] >= 0) & (c[..., 0] < nx) & (c[..., 1] >= 0) & (c[..., 1] < ny)

    def is_free(self, xy: np.ndarray) -> np.ndarray:
        """Boolean mask: point inside the grid and its cell is not occupied."""
        c = self.world_to_cell(xy)
        inside = self.in_bounds(xy)
        ny, nx = self.shape
        ix = np.clip(c[..., 0], 0, nx - 1)
        iy = np.clip(c[..., 1], 0, ny - 1)
        return inside & ~self.occupied[iy, ix]

    def sample_free(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` points ``(n, 2)`` drawn uniformly over the free space."""
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        corners = self._free_corners
        if corners.shape[0] == 0:
            raise ValueError("the grid has no free cell to sample from")
        out = rng.random((n, 2))
        out *= self.resolution
        out += corners[rng.integers(0, corners.shape[0], size=n)]
        return out

    @cached_property
    def _free_corners(self) -> np.ndarray:
        """World coordinates ``(n_free, 2)`` of the lower-left corners of the free cells."""
        iy, ix = np.nonzero(~self.occupied)
        return np.column_stack([ix, iy]) * self.resolution + np.asarray(self.origin)

    def memo(self, key: object, factory: Callable[[], object]) -> object:
        """Return the table cached on this grid under ``key``, building it with ``factory``.

        Lets every estimator that shares this map share its derived tables
        (e.g. likelihood fields) instead of each holding a copy.
        """
        if key not in self._cache:
            self._cache[key] = factory()
        return self._cache[key]

    # ------------------------------------------------------------ distance field
    def distance_field(self, pad_cells: int = 0) -> np.ndarray:
        """Distance in metres from each cell centre to the nearest occupied cell centre.

        Computed with :func:`scipy.ndimage.distance_transform_edt`. ``pad_cells``
        adds a border of free (unknown) cells around the map, so the result has
        shape ``(ny + 2 * pad, nx + 2 * pad)`` and cell ``(pad, pad)`` is the map's
        cell ``(0, 0)``. A map with no occupied cell gives ``inf`` everywhere.
        The unpadded field is cached on the grid.
        """
        if pad_cells < 0:
            raise ValueError(f"pad_cells must be >= 0, got {pad_cells}")
        key = ("dist", int(pad_cells))
        if key in self._cache:
            return self._cache[key]
        occ = np.pad(self.occupied, pad_cells, constant_values=False)
        if not occ.any():
            dist = np.full(occ.shape, np.inf)
        else:
            dist = ndimage.distance_transform_edt(~occ) * self.resolution
        dist.setflags(write=False)
        if pad_cells == 0:  # padded fields are one-off inputs to bigger tables
            self._cache[key] = dist
        return dist

    @cached_property
    def _clearance_cells(self) -> np.ndarray:
        """EDT (in cells) of the map surrounded by a one-cell occupied border, flattened."""
        occ = np.pad(self.occupied, 1, constant_values=True)
        return ndimage.distance_transform_edt(~occ).ravel()

    # --------------------------------------------------------------- ray casting
    def cast_rays(
        self,
        origins: np.ndarray,
        angles: np.ndarray,
        max_range: float,
    ) -> np.ndarray:
        """Range to the first occupied cell along each ray, capped at ``max_range``.

        ``origins`` ``(..., 2)`` and world ``angles`` ``(...)`` broadcast together.
        Vectorized over all rays: far from obstacles a ray jumps by its cell's
        clearance from the distance transform (minus a cell diagonal, so it
        never skips an obstacle); near obstacles it steps exactly to the next
        cell boundary (grid traversal), so the range is that of the first
        occupied cell's boundary crossed. Rays that start in an occupied cell
        or outside the map return 0.
        """
        if not np.isfinite(max_range) or max_range <= 0:
            raise ValueError(f"max_range must be a positive finite number, got {max_range}")
        origins = np.asarray(origins, dtype=float)
        angles = np.asarray(angles, dtype=float)
        if origins.shape[-1] != 2:
            raise ValueError(f"origins must have a trailing axis of 2, got shape {origins.shape}")
        ox_b, ang_b = np.broadcast_arrays(origins[..., 0], angles)
        oy_b = np.broadcast_to(origins[..., 1], ang_b.shape)
        out_shape = ang_b.shape
        res = self.resolution
        # Work in cell units of the 1-cell-padded grid.
        px = ((ox_b.ravel() - self.origin[0]) / res + 1.0).copy()
        py = ((oy_b.ravel() - self.origin[1]) / res + 1.0).copy()
        dx = np.cos(ang_b.ravel())
        dy = np.sin(ang_b.ravel())
        if not (np.all(np.isfinite(px)) and np.all(np.isfinite(py)) and np.all(np.isfinite(dx))):
            raise ValueError("ray origins and angles must be finite")
        ny, nx = self.shape
        nxp, nyp = nx + 2, ny + 2
        clearance = self._clearance_cells
        tmax = max_range / res
        t = np.zeros(px.size)
        active = np.arange(px.size)
        slack = np.sqrt(2.0)
        # axis-parallel rays never reach the boundaries they run along
        big = 4.0 * (tmax + 2.0)
        with np.errstate(divide="ignore"):
            inv_dx = np.where(np.abs(dx) > 1e-12, 1.0 / dx, big)
            inv_dy = np.where(np.abs(dy) > 1e-12, 1.0 / dy, big)
        while active.size:
            ta = t[active]
            dxa, dya = dx[active], dy[active]
            cx = px[active] + ta * dxa
            cy = py[active] + ta * dya
            fx = np.floor(cx)
            fy = np.floor(cy)
            ix = fx.astype(np.intp)
            iy = fy.astype(np.intp)
            inside = (ix >= 0) & (ix < nxp) & (iy >= 0) & (iy < nyp)
            clr = np.zeros(active.size)
            clr[inside] = clearance[iy[inside] * nxp + ix[inside]]
            hit = clr == 0.0
            # exact grid traversal (to the next cell boundary) near obstacles,
            # safe sphere-tracing jumps (clearance minus cell diagonal) far from them
            to_x = (fx + (dxa > 0) - cx) * inv_dx[active]
            to_y = (fy + (dya > 0) - cy) * inv_dy[active]
            to_x[np.abs(dxa) <= 1e-12] = big
            to_y[np.abs(dya) <= 1e-12] = big
            dda = np.minimum(np.abs(to_x), np.abs(to_y)) + 1e-6
            step = np.maximum(clr - slack, dda)
            ta = ta + np.where(hit, 0.0, step)
            done = hit | (ta >= tmax)
            t[active] = np.minimum(ta, tmax)
            active = active[~done]
        return (t * res).reshape(out_shape)

    def simulate_scan(
        self, pose: np.ndarray, beam_angles: np.ndarray, max_range: float
    ) -> np.ndarray:
        """Noise-free ranges of a scan taken at ``pose`` (x, y, heading) with robot-frame angles."""
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (3,):
            raise ValueError(f"pose must have shape (3,), got {pose.shape}")
        ang = pose[2] + np.asarray(beam_angles, dtype=float)
        return self.cast_rays(pose[:2], ang, max_range)
