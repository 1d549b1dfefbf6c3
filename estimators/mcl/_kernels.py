"""Compiled loops (numba, cached on disk) for the team particle-filter summaries.

Each kernel fuses what numpy would do in several passes with temporaries into
one or two passes over the particles. They are private helpers of
:mod:`estimators.mcl.batch`; inputs are checked there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["summary_features", "summary_sums"]


@njit(cache=True)
def summary_sums(
    flat: np.ndarray, w: np.ndarray, ends: np.ndarray,
    hist_cells: int, inv_cell: float, heading_bins: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """Per-segment weighted sums of particle sets stored back to back.

    ``flat`` holds ``x, y, heading`` in the block layout of
    :mod:`estimators.mcl._team_kernels`, ``w`` ``(N,)`` the weights (each segment's
    summing to 1), segment ``r`` ending (exclusive) at ``ends[r]``.
    Returns ``sums (R, 5)`` (weighted sums of ``x, y, cos, sin`` and of ``w**2``),
    ``cov (R, 3, 3)`` (about the weighted mean, the heading wrapped about the
    circular mean), ``hist (R, hist_cells**2)`` (weight in the egocentric grid
    of cells ``1 / inv_cell`` m, rows forward, columns from the right) and
    ``hhist (R, heading_bins)`` (weight per bin of heading minus the mean).
    """
    nr = ends.size
    sums = np.zeros((nr, 5))
    cov = np.zeros((nr, 3, 3))
    hist = np.zeros((nr, hist_cells * hist_cells))
    hhist = np.zeros((nr, heading_bins))
    half = hist_cells / 2.0
    two_pi = 2.0 * math.pi
    hscale = heading_bins / two_pi
    start = 0
    for r in range(nr):
        end = ends[r]
        sx = 0.0
        sy = 0.0
        sc = 0.0
        ss = 0.0
        s2 = 0.0
        n = end - start
        base = 3 * start
        for j in range(n):
            wi = w[start + j]
            h = flat[base + 2 * n + j]
            sx += wi * flat[base + j]
            sy += wi * flat[base + n + j]
            sc += wi * math.cos(h)
            ss += wi * math.sin(h)
            s2 += wi * wi
        sums[r, 0] = sx
        sums[r, 1] = sy
        sums[r, 2] = sc
        sums[r, 3] = ss
        sums[r, 4] = s2
        mh = math.atan2(ss, sc)
        cm = math.cos(mh) * inv_cell
        sm = math.sin(mh) * inv_cell
        c00 = 0.0
        c01 = 0.0
        c02 = 0.0
        c11 = 0.0
        c12 = 0.0
        c22 = 0.0
        for j in range(n):
            wi = w[start + j]
            dx = flat[base + j] - sx
            dy = flat[base + n + j] - sy
            dh = flat[base + 2 * n + j] - mh
            dh -= two_pi * math.floor(dh / two_pi + 0.5)
            c00 += wi * dx * dx
            c01 += wi * dx * dy
            c02 += wi * dx * dh
            c11 += wi * dy * dy
            c12 += wi * dy * dh
            c22 += wi * dh * dh
            fwd = math.floor(cm * dx + sm * dy + half)
            col = math.floor(half - (cm * dy - sm * dx))
            if 0.0 <= fwd < hist_cells and 0.0 <= col < hist_cells:
                hist[r, int(fwd) * hist_cells + int(col)] += wi
            b = int((dh + math.pi) * hscale)
            hhist[r, min(max(b, 0), heading_bins - 1)] += wi
        cov[r, 0, 0] = c00
        cov[r, 0, 1] = c01
        cov[r, 1, 0] = c01
        cov[r, 0, 2] = c02
        cov[r, 2, 0] = c02
        cov[r, 1, 1] = c11
        cov[r, 1, 2] = c12
        cov[r, 2, 1] = c12
        cov[r, 2, 2] = c22
        start = end
    return sums, cov, hist, hhist


@njit(cache=True)
def summary_features(
    flat: np.ndarray, w: np.ndarray, ends: np.ndarray, org: np.ndarray, bounds: np.ndarray,
    count_frac: np.ndarray, hist_cells: int, inv_cell: float, heading_bins: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """Means ``(R, 3)``, covariances ``(R, 3, 3)`` and belief features ``(R, F)`` float32
    (:func:`estimators.mcl.features.belief_features`' layout) of particle sets in the
    block layout, from :func:`summary_sums`; ``org (R, 2)``: each set's state origin,
    ``bounds (R, 4)``: its map's extent, ``count_frac (R,)``: its particle-count fraction."""
    sums, cov, hist, hhist = summary_sums(flat, w, ends, hist_cells, inv_cell, heading_bins)
    nr = ends.size
    nh = hist_cells * hist_cells
    nf = 15 + nh + heading_bins
    mean = np.empty((nr, 3))
    feats = np.empty((nr, nf), dtype=np.float32)
    start = 0
    for r in range(nr):
        count = ends[r] - start
        start = ends[r]
        mc = sums[r, 2]
        ms = sums[r, 3]
        mh = math.atan2(ms, mc)
        mx = sums[r, 0] + org[r, 0]
        my = sums[r, 1] + org[r, 1]
        mean[r, 0] = mx
        mean[r, 1] = my
        mean[r, 2] = mh
        res = math.hypot(mc, ms)
        sx = math.sqrt(max(cov[r, 0, 0], 0.0))
        sy = math.sqrt(max(cov[r, 1, 1], 0.0))
        sh = math.sqrt(max(cov[r, 2, 2], 0.0))
        circ = math.sqrt(-2.0 * math.log(min(max(res, 1e-300), 1.0)))
        f = feats[r]
        f[0] = (mx - bounds[r, 0]) / (bounds[r, 2] - bounds[r, 0]) * 2 - 1
        f[1] = (my - bounds[r, 1]) / (bounds[r, 3] - bounds[r, 1]) * 2 - 1
        f[2] = math.cos(mh)
        f[3] = math.sin(mh)
        f[4] = min(max(math.log10(max(sx, 1e-12)), -3.0), 2.0)
        f[5] = min(max(math.log10(max(sy, 1e-12)), -3.0), 2.0)
        f[6] = min(max(math.log10(max(circ, 1e-12)), -3.0), 2.0)
        k = 7
        for a, b, sa, sb in ((0, 1, sx, sy), (0, 2, sx, sh), (1, 2, sy, sh)):
            d = sa * sb
            c = cov[r, a, b] / d if d > 0 else 0.0
            f[k] = min(max(c, -1.0), 1.0)
            k += 1
        f[10] = res
        f[11] = 1.0 / sums[r, 4] / count
        total = 0.0
        for j in range(nh):
            total += hist[r, j]
        outside = max(0.0, 1.0 - total)
        ent = 0.0
        for j in range(nh + 1):
            m = hist[r, j] if j < nh else outside
            if m > 0:
                ent += m * math.log(m)
        f[12] = -ent / math.log(nh + 1)
        f[13] = count_frac[r]
        for j in range(nh):
            f[14 + j] = hist[r, j]
        f[14 + nh] = outside
        for j in range(heading_bins):
            f[15 + nh + j] = hhist[r, j]
    return mean, cov, feats


@njit(cache=True)
def beam_loglik(
    rows: np.ndarray, scales: np.ndarray, free_cells: np.ndarray, nx: int, ny: int,
    res: float, n_bins: int, max_range: float, flat: np.ndarray, angles: np.ndarray,
    lut: np.ndarray, inv_step: float, row_offsets: np.ndarray, ends: np.ndarray,
    occupied_loglik: float,
) -> np.ndarray:  # pragma: no cover (compiled)
    """Scan log-likelihoods ``(N,)`` of particle sets in the block layout of
    :mod:`estimators.mcl._team_kernels` (see :meth:`RangeTable.expected` and
    :meth:`BeamLUT.loglik`, whose float32 steps this repeats in the same order), plus
    ``occupied_loglik`` for particles outside the map's free cells.

    ``row_offsets (R, B)``: the likelihood-table row of robot ``r``'s reading of
    beam ``b``; segment ``r`` of the particles ends (exclusive) at ``ends[r]``.
    """
    nb = angles.size
    out = np.empty(ends[-1] if ends.size else 0)
    inv = np.float32(1.0 / res)
    res32 = np.float32(res)
    scale = np.float32(n_bins / (2.0 * math.pi))
    inv_scale = np.float32(1.0) / scale
    half_bins = np.float32(n_bins / 2)
    half = np.float32(0.5)
    rmax = np.float32(max_range)
    zero = np.float32(0.0)
    istep = np.float32(inv_step)
    s0, s1, s2, s3 = scales[0], scales[1], scales[2], scales[3]
    a_bins = np.empty(nb, dtype=np.float32)
    for b in range(nb):
        a_bins[b] = np.float32(angles[b]) * scale
    pow2 = (n_bins & (n_bins - 1)) == 0
    mask = n_bins - 1
    kis = np.empty(nb, dtype=np.int64)
    dphis = np.empty(nb, dtype=np.float32)
    start = 0
    for r_i in range(ends.size):
        end = ends[r_i]
        n = end - start
        base = 3 * start
        for j in range(n):
            x = flat[base + j]
            y = flat[base + n + j]
            ux = np.float32(np.rint(x * inv))
            uy = np.float32(np.rint(y * inv))
            ix = int(ux)
            iy = int(uy)
            dx = x - ux * res32
            dy = y - uy * res32
            inside = 0 <= ix < nx and 0 <= iy < ny
            cell = iy * nx + ix if inside else 0
            hb = flat[base + 2 * n + j] * scale + half_bins
            # the beams' table rows first (vectorizes), then the lookups: one
            # particle's beams read one cell's rows, close together in memory
            for b in range(nb):
                kf = hb + a_bins[b]
                k = np.float32(math.floor(kf))
                dphis[b] = ((kf - k) - half) * inv_scale
                ki = int(k)
                kis[b] = cell * n_bins + (ki & mask if pow2 else ki % n_bins)
            total = 0.0
            for b in range(nb):
                jr = kis[b]
                if inside:
                    r = np.float32(rows[jr, 0]) * s0
                    r += (np.float32(rows[jr, 1]) * s1) * dx
                    r += (np.float32(rows[jr, 2]) * s2) * dy
                    r += (np.float32(rows[jr, 3]) * s3) * dphis[b]
                    r = min(max(r, zero), rmax)
                else:
                    r = zero
                q = r * istep
                q += half
                total += lut[int(q) + row_offsets[r_i, b]]
            if not (inside and free_cells[cell]):
                total += occupied_loglik
            out[start + j] = total
        start = end
    return out


@njit(cache=True)
def tree_density(
    points: np.ndarray, low: np.ndarray, high: np.ndarray, split_dim: np.ndarray,
    split_val: np.ndarray, left: np.ndarray, density: np.ndarray,
) -> np.ndarray:  # pragma: no cover (compiled)
    """Density of a :class:`~estimators.mcl.density_tree.DensityTree` at ``points (M, d)``:
    descend from the root (node 0; a node's right child is ``left + 1``) to the leaf;
    0 outside ``[low, high)``."""
    m, d = points.shape
    out = np.zeros(m)
    for i in range(m):
        inside = True
        for j in range(d):
            if not (low[j] <= points[i, j] < high[j]):
                inside = False
                break
        if not inside:
            continue
        node = 0
        while split_dim[node] >= 0:
            if points[i, split_dim[node]] < split_val[node]:
                node = left[node]
            else:
                node = left[node] + 1
        out[i] = density[node]
    return out


@njit(cache=True)
def weighted_distances(
    flat: np.ndarray, w: np.ndarray, ends: np.ndarray, targets: np.ndarray,
) -> np.ndarray:  # pragma: no cover (compiled)
    """Per segment ``r`` of particles in the block layout: the weighted mean distance of
    the particles' positions from ``targets[r]`` (same coordinates)."""
    out = np.zeros(ends.size)
    start = 0
    for r in range(ends.size):
        n = ends[r] - start
        base = 3 * start
        tx = targets[r, 0]
        ty = targets[r, 1]
        acc = 0.0
        for j in range(n):
            dx = flat[base + j] - tx
            dy = flat[base + n + j] - ty
            acc += w[start + j] * math.sqrt(dx * dx + dy * dy)
        out[r] = acc
        start = ends[r]
    return out


@njit(cache=True)
def grow_tree(
    x: np.ndarray, w: np.ndarray, low: np.ndarray, high: np.ndarray, scale: np.ndarray,
    leaf_size: int, max_depth: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    # pragma: no cover (compiled)
    """Grow a :class:`~estimators.mcl.density_tree.DensityTree` breadth first.

    Nodes are processed in creation order (level by level); a node holding
    more than ``leaf_size`` samples above ``max_depth`` is halved along its
    longest scaled side, its children numbered consecutively. Each node's
    samples stay contiguous in a permutation (partitioned in place). Returns
    ``(lo, hi, split_dim, split_val, left, mass, depth)`` trimmed to the nodes.
    """
    m, d = x.shape
    cap = 1 + 2 * max_depth * (m // (leaf_size + 1) + 1)
    lo = np.empty((cap, d))
    hi = np.empty((cap, d))
    split_dim = np.full(cap, -1, dtype=np.intp)
    split_val = np.zeros(cap)
    left = np.full(cap, -1, dtype=np.intp)
    mass = np.zeros(cap)
    depth = np.zeros(cap, dtype=np.intp)
    first = np.zeros(cap, dtype=np.intp)
    last = np.zeros(cap, dtype=np.intp)
    order = np.arange(m)
    lo[0] = low
    hi[0] = high
    mass[0] = w.sum()
    last[0] = m
    n_nodes = 1
    node = 0
    deepest = 0
    while node < n_nodes:
        s, e = first[node], last[node]
        deepest = max(deepest, depth[node])
        if e - s > leaf_size and depth[node] < max_depth:
            k = 0
            best = (hi[node, 0] - lo[node, 0]) * scale[0]
            for j in range(1, d):
                ext = (hi[node, j] - lo[node, j]) * scale[j]
                if ext > best:
                    best = ext
                    k = j
            mid = 0.5 * (lo[node, k] + hi[node, k])
            # partition order[s:e]: samples below mid first
            i, j = s, e - 1
            while i <= j:
                if x[order[i], k] < mid:
                    i += 1
                else:
                    tmp = order[i]
                    order[i] = order[j]
                    order[j] = tmp
                    j -= 1
            c = n_nodes
            n_nodes += 2
            split_dim[node] = k
            split_val[node] = mid
            left[node] = c
            for child, cs, ce in ((c, s, i), (c + 1, i, e)):
                lo[child] = lo[node]
                hi[child] = hi[node]
                first[child] = cs
                last[child] = ce
                depth[child] = depth[node] + 1
                acc = 0.0
                for t in range(cs, ce):
                    acc += w[order[t]]
                mass[child] = acc
            hi[c, k] = mid
            lo[c + 1, k] = mid
        node += 1
    return (lo[:n_nodes].copy(), hi[:n_nodes].copy(), split_dim[:n_nodes].copy(),
            split_val[:n_nodes].copy(), left[:n_nodes].copy(), mass[:n_nodes].copy(), deepest)
