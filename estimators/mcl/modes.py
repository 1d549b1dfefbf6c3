"""A team's particle beliefs as maps and as modes: compiled passes over the block layout.

* :func:`raster_particles`: particle mass per cell of a regular grid and per
  heading bin, ``(R, headings, H, W)`` float32 for ``R`` particle sets;
* :func:`particle_modes`: the top-``K`` modes of each set (greedy clustering:
  seed at the heaviest ``radius``-sized cell and heading sector of the mass
  not yet assigned, take the unassigned particles within ``radius`` m and
  ``heading_tol`` rad of the seed's mean pose, repeat), ``(R, K, 6)`` rows
  ``weight, x, y, cos heading, sin heading, spread`` (spread: the weighted RMS
  distance of the mode's particles from its mean), sorted by weight, zero rows
  where fewer than ``K`` modes hold mass.

Both read particle sets in the block layout of :mod:`estimators.mcl._team_kernels`
(``flat`` float32, ``w`` weights, ``ends`` the segments' ends, ``org (R, 2)``
each set's state origin: world position = state + origin); that is what
:func:`estimators.mcl.batch.team_state` and :func:`~estimators.mcl.batch.team_weights`
return for a team of filters.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["particle_modes", "raster_particles"]

MODE_FIELDS = ("weight", "x", "y", "cos_heading", "sin_heading", "spread")


def _check(flat: np.ndarray, w: np.ndarray, ends: np.ndarray, org: np.ndarray) -> None:
    n = int(ends[-1]) if len(ends) else 0
    if flat.shape != (3 * n,) or w.shape != (n,) or org.shape != (len(ends), 2):
        raise ValueError(f"block layout mismatch: flat {flat.shape}, w {w.shape}, "
                         f"ends {ends.shape}, org {org.shape}")


def raster_particles(flat: np.ndarray, w: np.ndarray, ends: np.ndarray, org: np.ndarray,
                     x0: float, y0: float, cell_w: float, cell_h: float, width: int,
                     height: int, headings: int) -> np.ndarray:
    """``(R, headings, height, width)`` float32: each set's weight per grid cell and heading
    bin. Row ``iy`` covers world ``y`` in ``[y0 + iy cell_h, y0 + (iy + 1) cell_h)``, column
    ``ix`` likewise in ``x``; heading bin ``k`` covers ``[-pi + k d, -pi + (k + 1) d)``,
    ``d = 2 pi / headings``. Particles off the grid count in the nearest edge cell."""
    if width < 1 or height < 1 or headings < 1 or not (cell_w > 0 and cell_h > 0):
        raise ValueError(f"need width, height, headings >= 1 and cells > 0, got {width}, "
                         f"{height}, {headings}, {cell_w}, {cell_h}")
    flat, w = np.asarray(flat, np.float32), np.asarray(w, np.float64)
    ends, org = np.asarray(ends, np.intp), np.asarray(org, np.float64)
    _check(flat, w, ends, org)
    return _raster(flat, w, ends, org, float(x0), float(y0), 1.0 / cell_w, 1.0 / cell_h,
                   int(width), int(height), int(headings))


def particle_modes(flat: np.ndarray, w: np.ndarray, ends: np.ndarray, org: np.ndarray,
                   k: int, radius: float, heading_tol: float, bounds: tuple[float, ...]
                   ) -> np.ndarray:
    """``(R, k, 6)`` the top-``k`` modes of each set (module doc; fields :data:`MODE_FIELDS`).

    ``bounds = (x0, y0, x1, y1)``: the world extent the seeding histogram covers
    (particles outside count in its edge cells).
    """
    if k < 1 or not radius > 0 or not heading_tol > 0:
        raise ValueError(f"need k >= 1, radius > 0 and heading_tol > 0, got {k}, {radius}, "
                         f"{heading_tol}")
    flat, w = np.asarray(flat, np.float32), np.asarray(w, np.float64)
    ends, org = np.asarray(ends, np.intp), np.asarray(org, np.float64)
    _check(flat, w, ends, org)
    x0, y0, x1, y1 = (float(v) for v in bounds)
    nx = max(1, int(math.ceil((x1 - x0) / radius)))
    ny = max(1, int(math.ceil((y1 - y0) / radius)))
    return _modes(flat, w, ends, org, int(k), float(radius), float(heading_tol), x0, y0, nx, ny)


@njit(cache=True)
def _raster(flat, w, ends, org, x0, y0, inv_w, inv_h, width, height, headings
            ):  # pragma: no cover (compiled)
    nr = ends.size
    out = np.zeros((nr, headings, height, width), dtype=np.float32)
    scale = headings / (2.0 * math.pi)
    start = 0
    for r in range(nr):
        n = ends[r] - start
        base = 3 * start
        ox = org[r, 0] - x0
        oy = org[r, 1] - y0
        for j in range(n):
            ix = int(math.floor((flat[base + j] + ox) * inv_w))
            iy = int(math.floor((flat[base + n + j] + oy) * inv_h))
            h = flat[base + 2 * n + j] + math.pi
            ih = int(math.floor((h - 2.0 * math.pi * math.floor(h / (2.0 * math.pi))) * scale))
            ix = min(max(ix, 0), width - 1)
            iy = min(max(iy, 0), height - 1)
            ih = min(max(ih, 0), headings - 1)
            out[r, ih, iy, ix] += w[start + j]
        start = ends[r]
    return out


@njit(cache=True)
def _modes(flat, w, ends, org, k, radius, tol, x0, y0, nx, ny):  # pragma: no cover
    nr = ends.size
    sectors = 8
    nb = nx * ny * sectors
    out = np.zeros((nr, k, 6))
    two_pi = 2.0 * math.pi
    r2 = radius * radius
    inv = 1.0 / radius
    start = 0
    for r in range(nr):
        n = ends[r] - start
        base = 3 * start
        # per cell of the seeding histogram: mass, and weighted x, y, cos, sin sums
        # (offsets of the headings from their sector's centre: linear means, no trigonometry)
        hist = np.zeros((nb, 4))
        taken = np.zeros(n, dtype=np.bool_)
        cell = np.empty(n, dtype=np.int64)
        off = np.empty(n)
        for j in range(n):
            x = flat[base + j]
            y = flat[base + n + j]
            h = flat[base + 2 * n + j]
            ix = min(max(int(math.floor((x + org[r, 0] - x0) * inv)), 0), nx - 1)
            iy = min(max(int(math.floor((y + org[r, 1] - y0) * inv)), 0), ny - 1)
            u = (h + math.pi) / two_pi
            ih = min(max(int(math.floor((u - math.floor(u)) * sectors)), 0), sectors - 1)
            c = (iy * nx + ix) * sectors + ih
            cell[j] = c
            d = h - (-math.pi + (ih + 0.5) * two_pi / sectors)
            off[j] = d - two_pi * math.floor((d + math.pi) / two_pi)
            wj = w[start + j]
            hist[c, 0] += wj
            hist[c, 1] += wj * x
            hist[c, 2] += wj * y
            hist[c, 3] += wj * off[j]
        # particles bucketed by spatial cell (counting sort), so a mode's pass reads only
        # the 3 x 3 cells around its seed (a cell is ``radius`` wide)
        counts = np.zeros(nx * ny + 1, dtype=np.int64)
        for j in range(n):
            counts[cell[j] // sectors + 1] += 1
        for c in range(nx * ny):
            counts[c + 1] += counts[c]
        fill = counts[:-1].copy()
        order = np.empty(n, dtype=np.int64)
        for j in range(n):
            b = cell[j] // sectors
            order[fill[b]] = j
            fill[b] += 1
        found = 0
        for _ in range(k):
            best = 0
            for c in range(1, nb):
                if hist[c, 0] > hist[best, 0]:
                    best = c
            sw = hist[best, 0]
            if sw <= 1e-12:
                break
            cx = hist[best, 1] / sw  # the seed: the heaviest cell's weighted mean pose
            cy = hist[best, 2] / sw
            ch = -math.pi + (best % sectors + 0.5) * two_pi / sectors + hist[best, 3] / sw
            mw = 0.0
            mx = 0.0
            my = 0.0
            mh = 0.0
            mq = 0.0
            sxy = best // sectors
            bx = sxy % nx
            by = sxy // nx
            for qy in range(max(by - 1, 0), min(by + 2, ny)):
                for qx in range(max(bx - 1, 0), min(bx + 2, nx)):
                    q = qy * nx + qx
                    for t in range(counts[q], counts[q + 1]):
                        j = order[t]
                        if taken[j]:
                            continue
                        x = flat[base + j]
                        y = flat[base + n + j]
                        dx = x - cx
                        dy = y - cy
                        near = dx * dx + dy * dy <= r2
                        if near:
                            dh = flat[base + 2 * n + j] - ch
                            dh = dh - two_pi * math.floor((dh + math.pi) / two_pi)
                            near = abs(dh) <= tol
                        if not near and cell[j] != best:
                            continue
                        # members, and the seed cell's particles beyond the tolerance
                        # (dropped, so the same seed is not drawn again)
                        taken[j] = True
                        wj = w[start + j]
                        c = cell[j]
                        hist[c, 0] -= wj
                        hist[c, 1] -= wj * x
                        hist[c, 2] -= wj * y
                        hist[c, 3] -= wj * off[j]
                        if near:
                            mw += wj
                            mx += wj * x
                            my += wj * y
                            mh += wj * dh
                            mq += wj * (x * x + y * y)
            hist[best, :] = 0.0
            if mw <= 0.0:
                continue
            ax = mx / mw
            ay = my / mw
            head = ch + mh / mw
            out[r, found, 0] = mw
            out[r, found, 1] = ax + org[r, 0]
            out[r, found, 2] = ay + org[r, 1]
            out[r, found, 3] = math.cos(head)
            out[r, found, 4] = math.sin(head)
            out[r, found, 5] = math.sqrt(max(mq / mw - ax * ax - ay * ay, 0.0))
            found += 1
        # sort the found modes by weight, heaviest first (insertion sort: k is small)
        for a in range(1, found):
            row = out[r, a].copy()
            b = a - 1
            while b >= 0 and out[r, b, 0] < row[0]:
                out[r, b + 1] = out[r, b]
                b -= 1
            out[r, b + 1] = row
        start = ends[r]
    return out
