"""Geodesic path planning on the known map: a coarse grid of drivable cells and Dijkstra.

:class:`PlanGrid` resamples a known occupancy grid
(:class:`estimators.mcl.occupancy.OccupancyGrid`) into cells of ``cell`` m whose centres
keep at least ``clearance`` m from every obstacle, links each to its 8 neighbours
(edge cost: the step length, raised near the walls so paths keep to the middle
of a corridor) and answers geodesic distances and paths with
:func:`scipy.sparse.csgraph.dijkstra`. Points off the drivable cells snap to
the nearest drivable one.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import sparse
from scipy.ndimage import distance_transform_edt
from scipy.sparse.csgraph import dijkstra

WALL_COST = 2.0  # extra cost per metre driven, per metre of clearance short of PREFERRED
PREFERRED = 1.0  # m: clearance from which a cell costs its plain length


class PlanGrid:
    """Drivable cells of a known map, with geodesic distances between them (module doc).

    Args:
        grid: the known occupancy grid (world frame).
        world_size: ``(W, H)`` m: the planning grid covers ``[0, W] x [0, H]``.
        cell: m, the planning cell edge.
        clearance: m, the least distance of a drivable cell's centre from an obstacle.
    """

    def __init__(self, grid, world_size: tuple[float, float], cell: float = 0.5,
                 clearance: float = 0.5) -> None:
        if not (cell > 0 and clearance >= 0):
            raise ValueError(f"need cell > 0 and clearance >= 0, got {cell}, {clearance}")
        w, h = (float(v) for v in world_size)
        self.grid = grid
        self.cell = float(cell)
        self.nx, self.ny = max(1, int(w // cell)), max(1, int(h // cell))
        xs = (np.arange(self.nx) + 0.5) * cell
        ys = (np.arange(self.ny) + 0.5) * cell
        centres = np.stack(np.meshgrid(xs, ys), axis=-1)  # (ny, nx, 2)
        # clearance of each centre: the fine grid's distance field, read at the centre
        fine = distance_transform_edt(~grid.occupied) * grid.resolution
        c = grid.world_to_cell(centres)
        fy, fx = fine.shape
        inside = (c[..., 0] >= 0) & (c[..., 0] < fx) & (c[..., 1] >= 0) & (c[..., 1] < fy)
        clear = np.where(inside, fine[np.clip(c[..., 1], 0, fy - 1), np.clip(c[..., 0], 0,
                                                                                fx - 1)], 0.0)
        clear = clear - 0.5 * grid.resolution  # centre to the occupied cell's edge
        self.clearance = clear.ravel()
        self.free = self.clearance >= clearance
        self.centres = centres.reshape(-1, 2)
        self.free_index = np.flatnonzero(self.free)
        self.graph = self._graph()
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _graph(self) -> sparse.csr_matrix:
        nx, ny = self.nx, self.ny
        rows, cols, costs = [], [], []
        penalty = 1.0 + WALL_COST * np.maximum(PREFERRED - self.clearance, 0.0)
        iy, ix = np.divmod(np.arange(nx * ny), nx)
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            jx, jy = ix + dx, iy + dy
            ok = (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny)
            a = np.flatnonzero(ok)
            b = jy[ok] * nx + jx[ok]
            keep = self.free[a] & self.free[b]
            if dx and dy:  # a diagonal step needs both side cells free (no corner cutting)
                keep &= self.free[iy[a] * nx + jx[a]] & self.free[jy[a] * nx + ix[a]]
            a, b = a[keep], b[keep]
            length = self.cell * math.hypot(dx, dy)
            cost = length * 0.5 * (penalty[a] + penalty[b])
            rows += [a, b]
            cols += [b, a]
            costs += [cost, cost]
        n = nx * ny
        return sparse.csr_matrix((np.concatenate(costs), (np.concatenate(rows),
                                                          np.concatenate(cols))), shape=(n, n))

    def cell_of(self, xy: np.ndarray) -> np.ndarray:
        """Index of the drivable cell nearest each world point ``(..., 2)`` (shape ``(...)``)."""
        xy = np.asarray(xy, dtype=float)
        pts = xy.reshape(-1, 2)
        ix = np.clip(np.floor(pts[:, 0] / self.cell).astype(np.intp), 0, self.nx - 1)
        iy = np.clip(np.floor(pts[:, 1] / self.cell).astype(np.intp), 0, self.ny - 1)
        idx = iy * self.nx + ix
        bad = np.flatnonzero(~self.free[idx])
        if len(bad) and len(self.free_index):
            free = self.centres[self.free_index]
            d = np.hypot(free[None, :, 0] - pts[bad, None, 0], free[None, :, 1] - pts[bad, None, 1])
            idx[bad] = self.free_index[np.argmin(d, axis=1)]
        return idx.reshape(xy.shape[:-1])

    def distances(self, source: int) -> tuple[np.ndarray, np.ndarray]:
        """Geodesic costs from drivable cell ``source`` to every cell (``inf`` where not
        reachable) and the predecessors (-9999 at the source), cached per source."""
        hit = self._cache.get(int(source))
        if hit is None:
            dist, pred = dijkstra(self.graph, indices=int(source), return_predecessors=True)
            if len(self._cache) > 64:
                self._cache.clear()
            hit = self._cache[int(source)] = (dist, pred)
        return hit

    def path(self, source: int, target: int) -> np.ndarray:
        """World points ``(P, 2)`` of the cells from ``source`` to ``target`` (both in)."""
        _, pred = self.distances(source)
        cells = [int(target)]
        while cells[-1] != source and pred[cells[-1]] >= 0 and len(cells) <= self.nx * self.ny:
            cells.append(int(pred[cells[-1]]))
        if cells[-1] != source:
            return self.centres[[source]]
        return self.centres[cells[::-1]]
