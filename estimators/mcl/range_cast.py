"""A compiled builder of :class:`~estimators.mcl.beam_table.RangeTable`, for maps drawn often.

:func:`estimators.mcl.beam_table.range_table` builds a map's table with vectorized
ray casts (about 2 s for a 40 m sonar map at 0.25 m); a scenario that draws a new map
every episode cannot wait that long at each reset. :func:`prepare_range_table` builds
the same table in one compiled pass (grid traversal from every free cell centre along
every bin's central direction, then the cone's nearest ray and the first-order
corrections exactly as ``range_table`` derives them) and stores it in
``range_table``'s cache, so the filters that ask for it next find it there. Ranges
agree with the vectorized casts to float rounding (``tests/estimators/mcl``).

Only cones whose rays fall on bin centres are built here (every shipped sonar: three
rays over 22.5 degrees on 256 bins); other tables are left to ``range_table``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.mcl import beam_table
from estimators.mcl.occupancy import OccupancyGrid


@njit(cache=True)
def _cast_all(occ: np.ndarray, free: np.ndarray, res: float, ox: float, oy: float,
              phi: np.ndarray, max_range: float) -> np.ndarray:
    """``(F, B)`` range (m) from each free cell's centre along each direction ``phi``: the
    distance to the first occupied cell's boundary (cells off the grid are occupied),
    capped at ``max_range``."""
    ny, nx = occ.shape
    nb = phi.size
    out = np.empty((free.size, nb))
    cs, sn = np.cos(phi), np.sin(phi)
    tcap = max_range / res
    for f in range(free.size):
        cx = free[f] % nx
        cy = free[f] // nx
        for b in range(nb):
            dx, dy = cs[b], sn[b]
            ix, iy = cx, cy
            # the start is the cell centre (cell units: cell i covers [i, i + 1))
            if abs(dx) > 1e-12:
                stepx = 1 if dx > 0 else -1
                tdx = abs(1.0 / dx)
                tmx = 0.5 * tdx
            else:
                stepx, tdx, tmx = 0, np.inf, np.inf
            if abs(dy) > 1e-12:
                stepy = 1 if dy > 0 else -1
                tdy = abs(1.0 / dy)
                tmy = 0.5 * tdy
            else:
                stepy, tdy, tmy = 0, np.inf, np.inf
            t = 0.0
            while True:
                if tmx < tmy:
                    t = tmx
                    tmx += tdx
                    ix += stepx
                else:
                    t = tmy
                    tmy += tdy
                    iy += stepy
                if t >= tcap:
                    t = tcap
                    break
                if ix < 0 or ix >= nx or iy < 0 or iy >= ny or occ[iy, ix]:
                    break
            out[f, b] = t * res
    return out


@njit(cache=True)
def _rows(ranges: np.ndarray, free: np.ndarray, nx: int, res: float, ox: float, oy: float,
          phi: np.ndarray, shifts: np.ndarray, max_range: float, max_slope: float,
          scales: np.ndarray, n_cells: int) -> np.ndarray:
    """The table's int16 rows ``(n_cells * B, 4)``: per free cell and bin, the nearest of
    the cone's rays (bins ``b + shifts``, the first on ties) and its derivatives by the
    origin's x, y and by the direction, as ``beam_table`` derives them."""
    nb = phi.size
    rows = np.zeros((n_cells * nb, 4), dtype=np.int16)
    cs, sn = np.cos(phi), np.sin(phi)
    vals = np.empty(4, dtype=np.float32)
    cone = np.empty((nb, shifts.size), dtype=np.int64)  # the bins of each bin's cone rays
    for b in range(nb):
        for k in range(shifts.size):
            cone[b, k] = (b + shifts[k]) % nb
    for f in range(free.size):
        cell = free[f]
        px = (cell % nx + 0.5) * res + ox
        py = (cell // nx + 0.5) * res + oy
        ray = ranges[f]
        for b in range(nb):
            best = cone[b, 0]
            r = ray[best]
            for k in range(1, shifts.size):
                v = ray[cone[b, k]]
                if v < r:
                    r = v
                    best = cone[b, k]
            cos, sin = cs[best], sn[best]
            hx = (px + r * cos - ox) / res
            hy = (py + r * sin - oy) / res
            on_x = abs(hx - np.rint(hx)) < 1e-3
            on_y = abs(hy - np.rint(hy)) < 1e-3
            hit = r > 0 and r < max_range
            vert = hit and on_x and ((not on_y) or abs(cos) > abs(sin))
            horiz = hit and on_y and not vert
            gx = -1.0 / cos if vert else 0.0
            gy = -1.0 / sin if horiz else 0.0
            if vert:
                gphi = r * sin / cos
            elif horiz:
                gphi = -r * cos / sin
            else:
                gphi = 0.0
            gx = min(max(gx, -max_slope), max_slope)
            gy = min(max(gy, -max_slope), max_slope)
            gphi = min(max(gphi, -max_slope * r), max_slope * r)
            vals[0], vals[1], vals[2], vals[3] = r, gx, gy, gphi
            row = cell * nb + b
            for c in range(4):
                rows[row, c] = np.int16(np.rint(np.float64(vals[c]) / scales[c]))
    return rows


def build_range_table(grid: OccupancyGrid, max_range: float, n_bins: int = 256,
                      cone_half_width: float = 0.0, rays_per_cone: int = 1
                      ) -> beam_table.RangeTable | None:
    """The :class:`RangeTable` ``range_table`` would build for these parameters, built in a
    compiled pass; ``None`` when the cone's rays do not fall on bin centres."""
    rays = int(rays_per_cone) if cone_half_width > 0 else 1
    cone = float(cone_half_width) if rays > 1 else 0.0
    bw = 2.0 * math.pi / n_bins
    offsets = np.linspace(-cone, cone, rays) if rays > 1 and cone > 0 else np.zeros(1)
    shifts = offsets / bw
    if not np.all(np.abs(shifts - np.rint(shifts)) < 1e-9):
        return None
    ny, nx = grid.shape
    res = float(grid.resolution)
    ox, oy = (float(v) for v in grid.origin)
    occ = np.ascontiguousarray(grid.occupied)
    free = np.flatnonzero(~occ.ravel())
    phi = -math.pi + (np.arange(n_bins) + 0.5) * bw
    ranges = _cast_all(occ, free, res, ox, oy, phi, float(max_range))
    max_slope = beam_table.MAX_SLOPE
    scales = np.array([1.0, max_slope, max_slope, max_slope * max_range]) / 32767.0
    scales[0] *= max_range
    rows = _rows(ranges, free, nx, res, ox, oy, phi, np.rint(shifts).astype(np.int64),
                 float(max_range), float(max_slope), scales, ny * nx)
    rows.flags.writeable = False
    scales = scales.astype(np.float32)
    scales.flags.writeable = False
    free_cells = ~occ.ravel()
    free_cells.flags.writeable = False
    return beam_table.RangeTable(rows, n_bins, nx, ny, res, (ox + 0.5 * res, oy + 0.5 * res),
                                 float(max_range), cone, int(offsets.size), free_cells, scales)


def prepare_range_table(grid: OccupancyGrid, max_range: float, n_bins: int = 256,
                        cone_half_width: float = 0.0, rays_per_cone: int = 1) -> bool:
    """Build ``grid``'s table (:func:`build_range_table`) into ``range_table``'s cache unless
    it is there; whether the table is cached now."""
    key = beam_table.table_key(grid, max_range, n_bins, cone_half_width, rays_per_cone)
    if beam_table.cached_table(key) is not None:
        return True
    table = build_range_table(grid, max_range, n_bins, cone_half_width, rays_per_cone)
    if table is None:
        return False
    beam_table.remember_table(key, table)
    return True
