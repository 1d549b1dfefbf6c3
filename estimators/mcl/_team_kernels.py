"""Compiled loops (numba, cached on disk) over a team's particle sets in one flat array.

The "block layout": robot ``r``'s particles ``start_r .. end_r - 1`` (``end_r =
ends[r]``, ``start_r`` the previous end) have their float32 ``x, y, heading``
rows stored as one C-ordered ``(3, n_r)`` block at offset ``3 * start_r`` of a
flat array, so each filter's ``(3, n_r)`` state is a contiguous view of the team
array and one call updates every robot. Weights and other per-particle values
are flat ``(N,)`` arrays. Private helpers of :mod:`estimators.mcl.batch`,
:mod:`estimators.mcl.weighting`, :mod:`estimators.mcl.sampling` and
:class:`estimators.mcl.filter.ParticleFilter` (one filter is a team of one);
inputs are checked there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "build_blocks", "compose_rows", "lf_scan_rows", "normals_from_bits", "predict_blocks",
    "select_blocks", "weigh_blocks", "ziggurat_tables",
]

# fix columns of weigh_blocks: [gps?, gx, gy, -0.5 / var, compass?, heading, -0.5 / std**2]
FIX_COLUMNS = 7


@njit(cache=True)
def compose_rows(v: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:  # pragma: no cover
    """Relative motions ``(R, 3)`` of unicycle odometry sub-steps ``v, w (R, K)`` held for
    ``dt`` each (exact arcs, in the robot frame at the start); ``nan`` rows where an input
    is not finite (:func:`estimators.mcl.batch.compose_odometry_batch`)."""
    nr, k = v.shape
    out = np.zeros((nr, 3))
    for r in range(nr):
        th = 0.0
        x = 0.0
        y = 0.0
        for j in range(k):
            dth = w[r, j] * dt
            if abs(dth) > 1e-9:
                lx = v[r, j] / w[r, j] * math.sin(dth)
                ly = v[r, j] / w[r, j] * (1.0 - math.cos(dth))
            else:
                lx = v[r, j] * dt
                ly = 0.0
            c = math.cos(th)
            s = math.sin(th)
            x += c * lx - s * ly
            y += s * lx + c * ly
            th += dth
        out[r, 0] = x
        out[r, 1] = y
        out[r, 2] = th
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
            out[r, 0] = np.nan
    return out


@njit(cache=True)
def predict_blocks(
    flat: np.ndarray, z: np.ndarray, params: np.ndarray, ends: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Odometry motion of every particle, in place (the rot1 / trans / rot2 model).

    ``z`` holds standard normals in the block layout; ``params (R, 6)`` float32
    per robot: ``rot1, trans, rot2`` and their noise standard deviations. A
    particle turns by ``rot1 + sd_r1 z0``, moves ``trans + sd_t z1`` along its
    new heading and turns by ``rot2 + sd_r2 z2`` (float32 throughout).
    """
    start = 0
    for r in range(ends.size):
        end = ends[r]
        n = end - start
        base = 3 * start
        rot1 = params[r, 0]
        trans = params[r, 1]
        rot2 = params[r, 2]
        sd1 = params[r, 3]
        sdt = params[r, 4]
        sd2 = params[r, 5]
        for j in range(n):
            h = flat[base + 2 * n + j] + (rot1 + sd1 * z[base + j])
            t = trans + sdt * z[base + n + j]
            flat[base + j] += math.cos(h) * t
            flat[base + n + j] += math.sin(h) * t
            flat[base + 2 * n + j] = h + (rot2 + sd2 * z[base + 2 * n + j])
        start = end


@njit(cache=True)
def lf_scan_rows(
    ranges: np.ndarray, unit_x: np.ndarray, unit_y: np.ndarray, reach: float, max_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """The likelihood-field scans of robots' readings ``ranges (R, B)`` as
    :func:`weigh_blocks` reads them: endpoints ``ux, uy (R, B)`` float32 in cells in the
    robot frame (NaN: no endpoint, for readings not below ``max_range``), each
    ``float32(unit * min(range, reach))`` with ``unit_x, unit_y (B,)`` float32 (as
    :func:`estimators.mcl.likelihood_field.lf_endpoints` rounds them); the beam counts
    ``nb (R,)`` (-1 for a row of NaN: no scan) and the endpoint counts ``k (R,)``."""
    nr, nbeams = ranges.shape
    ux = np.empty((nr, nbeams), dtype=np.float32)
    uy = np.empty((nr, nbeams), dtype=np.float32)
    nb = np.empty(nr, dtype=np.intp)
    k = np.zeros(nr, dtype=np.intp)
    for r in range(nr):
        scan = False
        for b in range(nbeams):
            z = ranges[r, b]
            scan = scan or z == z
            if z < max_range:
                k[r] += 1
                zc = min(z, reach)
                ux[r, b] = np.float32(np.float64(unit_x[b]) * zc)
                uy[r, b] = np.float32(np.float64(unit_y[b]) * zc)
            else:
                ux[r, b] = np.nan
                uy[r, b] = np.nan
        nb[r] = k[r] if scan else -1
    return ux, uy, nb, k


@njit(cache=True)
def weigh_blocks(
    flat: np.ndarray, ends: np.ndarray, w_prev: np.ndarray,
    table: np.ndarray, nxp: int, offset: int, pad: np.float32, inv_res: np.float32,
    lo_x: np.float32, lo_y: np.float32, hi_x: np.float32, hi_y: np.float32,
    ux: np.ndarray, uy: np.ndarray, nb: np.ndarray, power: float, fix: np.ndarray,
    loglik: np.ndarray, scored: bool, w: np.ndarray, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Weight every robot's particles by its laser scan (likelihood field) and fixes.

    Robot ``r`` with ``nb[r] >= 0`` has a scan of ``nb[r]`` endpoints: the finite
    ``ux[r, b], uy[r, b]`` (float32, cells; NaN: no endpoint) in its frame. Each
    particle's scan score is the float32 sum, in this order, of the field's penalty
    at its own cell and the field at its endpoints (as
    :func:`estimators.mcl.likelihood_field.lf_loglik` computes it), ``loglik = power *
    score`` (float64). ``fix[r]`` adds a DGPS
    position factor ``exp(-0.5 |p - g|^2 / var) + 1e-12`` and a compass factor
    ``exp(-0.5 e^2 / std^2) + 1e-12`` (``e`` the wrapped heading error) when
    their flags are set. A robot with neither keeps ``w_prev``. With ``scored``
    the scan log-likelihoods are already in ``loglik`` (any scan model; the field
    arguments are then unused).

    Writes the normalized weights ``w`` and
    ``out[r] = (log sum w_prev exp(loglik - m) + m, ess, ok)``: the scan's log
    evidence less the field's constant (``nan`` without a scan), the effective
    sample size, and 1, or 0 where the weights underflowed (``w`` then holds
    garbage for that robot and the caller redoes it).
    """
    two_pi = 2.0 * math.pi
    row = np.int32(nxp)  # cell (ix, iy) of the field is entry iy * nxp + ix
    start = 0
    for r in range(ends.size):
        end = ends[r]
        n = end - start
        base = 3 * start
        scan = nb[r] >= 0
        gps = fix[r, 0] != 0.0
        compass = fix[r, 4] != 0.0
        m = 0.0
        if scan and not scored:
            # beams outer, particles inner: the index arithmetic vectorizes and the
            # gathers run in a tight loop (each particle's float32 sum keeps its order)
            xs = np.empty(n, dtype=np.float32)
            ys = np.empty(n, dtype=np.float32)
            cs = np.empty(n, dtype=np.float32)
            ss = np.empty(n, dtype=np.float32)
            acc = np.empty(n, dtype=np.float32)
            ind = np.empty(n, dtype=np.int32)
            for j in range(n):
                x = min(max(flat[base + j], lo_x), hi_x) * inv_res + pad
                y = min(max(flat[base + n + j], lo_y), hi_y) * inv_res + pad
                h = flat[base + 2 * n + j]
                xs[j] = x
                ys[j] = y
                cs[j] = math.cos(h)
                ss[j] = math.sin(h)
                acc[j] = table[offset + int(np.rint(y)) * nxp + int(np.rint(x))]
            for b in range(ux.shape[1]):
                u = ux[r, b]
                v = uy[r, b]
                if u != u:  # NaN: no endpoint
                    continue
                for j in range(n):
                    ex = xs[j] + cs[j] * u - ss[j] * v
                    ey = ys[j] + ss[j] * u + cs[j] * v
                    ind[j] = np.int32(np.rint(ey)) * row + np.int32(np.rint(ex))
                for j in range(n):
                    acc[j] += table[np.uint32(ind[j])]
            for j in range(n):
                loglik[start + j] = power * np.float64(acc[j])
        if scan:
            m = -np.inf
            for i in range(start, end):
                m = max(m, loglik[i])
        gx = fix[r, 1]
        gy = fix[r, 2]
        gc = fix[r, 3]
        ch = fix[r, 5]
        cc = fix[r, 6]
        sum1 = 0.0
        sum2 = 0.0
        for j in range(n):
            i = start + j
            a = w_prev[i]
            if scan:
                d = loglik[i] - m
                # below exp's normal range the weight is 0 (a subnormal exp is slow)
                a = a * math.exp(d) if d > -708.0 else 0.0
            sum1 += a
            # exp(q) + 1e-12 is exactly 1e-12 for q <= -70: skip the exp there
            if gps:
                dx = flat[base + j] - gx
                dy = flat[base + n + j] - gy
                q = gc * (dx * dx + dy * dy)
                a *= math.exp(q) + 1e-12 if q > -70.0 else 1e-12
            if compass:
                e = flat[base + 2 * n + j] - ch
                e -= two_pi * np.rint(e / two_pi)
                q = cc * e * e
                a *= math.exp(q) + 1e-12 if q > -70.0 else 1e-12
            w[i] = a
            sum2 += a
        ok = sum2 > 0.0 and sum2 < np.inf and sum1 > 0.0
        out[r, 0] = m + math.log(sum1) if scan and ok else np.nan
        out[r, 2] = 1.0 if ok else 0.0
        if ok:
            inv = 1.0 / sum2
            sq = 0.0
            for i in range(start, end):
                wi = w[i] * inv
                w[i] = wi
                sq += wi * wi
            out[r, 1] = 1.0 / sq
        start = end


@njit(cache=True)
def select_blocks(
    flat: np.ndarray, w: np.ndarray, ends: np.ndarray, mode: np.ndarray, u: np.ndarray,
    m: np.ndarray, bits: np.ndarray, kld: np.ndarray, need: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """Low-variance resampling of every robot with ``mode[r]`` 1 (fixed count) or 2
    (KLD-sampling); ``mode`` 0 robots are skipped.

    Robot ``r`` draws ``m[r]`` indices into its own particles with offset ``u[r]``
    (as :func:`estimators.mcl.sampling.low_variance_from_cumulative` does from
    its weights' cumulative sums); with KLD-sampling they are shuffled (Fisher-Yates
    forward: position ``i`` swaps with ``i + floor(u (m[r] - i))``, ``u`` the top 53
    bits of ``bits[o_r + i]``; ``o_r`` the sum of the earlier ``m``) only as far as the
    count kept: the shortest prefix that reaches the bound ``need[int(kld[r, 6]) + k]``
    for the ``k`` histogram bins it occupies, clipped to ``[kld[r, 7], m[r]]``
    (``kld[r]``: ``org_x, org_y, 1 / bin_x, 1 / bin_y, 1 / bin_heading, n_heading_bins,
    need offset, n_min``; headings must be wrapped). Returns the indices (at offsets
    ``o_r``) and the counts ``(R,)`` (``m[r]`` for fixed counts).
    """
    nr = ends.size
    total_m = 0
    for r in range(nr):
        total_m += m[r]
    idx = np.empty(total_m, dtype=np.intp)
    counts = m.copy()
    start = 0
    o = 0
    for r in range(nr):
        end = ends[r]
        n = end - start
        mr = m[r]
        if mode[r] == 0:
            start = end
            continue
        total = 0.0
        for i in range(start, end):
            total += w[i]
        scale = mr / total
        # pointer j goes to the first particle whose ceil(cum * m / total - u) exceeds j
        i = 0
        acc = w[start]
        below = math.ceil(acc * scale - u[r]) if n > 1 else mr
        for j in range(mr):
            while below <= j:
                i += 1
                acc += w[start + i]
                below = math.ceil(acc * scale - u[r]) if i < n - 1 else mr
            idx[o + j] = i
        if mode[r] == 2 and mr > 0:
            # histogram bin of each of the robot's particles
            base = 3 * start
            org_x, org_y = kld[r, 0], kld[r, 1]
            inv_bx, inv_by, inv_bt = kld[r, 2], kld[r, 3], kld[r, 4]
            n_t = int(kld[r, 5])
            kx = np.empty(n, dtype=np.int64)
            ky = np.empty(n, dtype=np.int64)
            for p in range(n):
                kx[p] = np.int64(math.floor((np.float64(flat[base + p]) + org_x) * inv_bx))
                ky[p] = np.int64(math.floor((np.float64(flat[base + n + p]) + org_y) * inv_by))
            kx0 = kx.min()
            ky0 = ky.min()
            ny_b = ky.max() - ky0 + 1
            size = (kx.max() - kx0 + 1) * ny_b * n_t
            dense = size <= 16 * mr + 2**20  # a marker array of this size is cheap
            seen = np.zeros(size if dense else 1, dtype=np.bool_)
            seen_set = {np.int64(-1)}
            # shuffle forward (Fisher-Yates: position i takes a uniform pick of the rest)
            # and stop at the shortest prefix that reaches the bound
            off = int(kld[r, 6])
            k = 0
            keep = mr
            for i in range(mr):
                u53 = np.float64(bits[o + i] >> np.uint64(11)) * (1.0 / 9007199254740992.0)
                j = i + int(u53 * (mr - i))
                p = idx[o + j]
                idx[o + j] = idx[o + i]
                idx[o + i] = p
                h = flat[base + 2 * n + p]
                t = np.int64(math.floor((h + np.float32(math.pi)) * np.float32(inv_bt)))
                t = min(max(t, 0), n_t - 1)
                key = ((kx[p] - kx0) * ny_b + (ky[p] - ky0)) * n_t + t
                if dense:
                    if not seen[key]:
                        seen[key] = True
                        k += 1
                elif key not in seen_set:
                    seen_set.add(key)
                    k += 1
                if i + 1 >= need[off + k]:  # need >= n_min: the prefix is shuffled
                    keep = i + 1
                    break
            counts[r] = min(max(keep, int(kld[r, 7])), mr)
        o += mr
        start = end
    return idx, counts


@njit(cache=True)
def build_blocks(
    flat: np.ndarray, ends: np.ndarray, mode: np.ndarray, idx: np.ndarray, m: np.ndarray,
    keep: np.ndarray, inj_xy: np.ndarray, inj_h: np.ndarray, n_inj: np.ndarray,
    org: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover (compiled)
    """The team's state after resampling (block layout) and its segment ends.

    Robot ``r`` with ``mode[r]`` 0 keeps its particles; otherwise its new set is
    the first ``keep[r]`` particles of :func:`select_blocks`' indices (at the
    offsets of ``m``) followed by ``n_inj[r]`` injected world poses, in robot order:
    positions ``inj_xy (K, 2)`` and headings ``inj_h (K,)`` (float64), moved to state
    coordinates (``org (R, 2)``) with the headings wrapped to ``[-pi, pi)``.
    """
    nr = ends.size
    new_ends = np.empty(nr, dtype=np.intp)
    total = 0
    start = 0
    for r in range(nr):
        total += (ends[r] - start) if mode[r] == 0 else keep[r] + n_inj[r]
        new_ends[r] = total
        start = ends[r]
    out = np.empty(3 * total, dtype=np.float32)
    two_pi = 2.0 * math.pi
    below_pi = np.nextafter(math.pi, 0.0)
    start = 0
    new_start = 0
    o = 0
    q = 0
    for r in range(nr):
        n = ends[r] - start
        base = 3 * start
        nn = new_ends[r] - new_start
        nbase = 3 * new_start
        if mode[r] == 0:
            for j in range(3 * n):
                out[nbase + j] = flat[base + j]
        else:
            for j in range(keep[r]):
                p = idx[o + j]
                out[nbase + j] = flat[base + p]
                out[nbase + nn + j] = flat[base + n + p]
                out[nbase + 2 * nn + j] = flat[base + 2 * n + p]
            for j in range(keep[r], nn):
                out[nbase + j] = np.float32(inj_xy[q, 0] - org[r, 0])
                out[nbase + nn + j] = np.float32(inj_xy[q, 1] - org[r, 1])
                h = (inj_h[q] + math.pi) % two_pi - math.pi
                out[nbase + 2 * nn + j] = np.float32(min(h, below_pi))
                q += 1
        o += m[r]
        start = ends[r]
        new_start = new_ends[r]
    return out, new_ends


def ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Marsaglia and Tsang's 128-layer ziggurat for the standard normal: ``(kn, wn, fn)``."""
    m1 = 2147483648.0
    dn = tn = 3.442619855899
    vn = 9.91256303526217e-3
    kn = np.zeros(128)
    wn = np.zeros(128)
    fn = np.zeros(128)
    q = vn / math.exp(-0.5 * dn * dn)
    kn[0] = dn / q * m1
    kn[1] = 0.0
    wn[0] = q / m1
    wn[127] = dn / m1
    fn[0] = 1.0
    fn[127] = math.exp(-0.5 * dn * dn)
    for i in range(126, 0, -1):
        dn = math.sqrt(-2.0 * math.log(vn / dn + math.exp(-0.5 * dn * dn)))
        kn[i + 1] = dn / tn * m1
        tn = dn
        fn[i] = math.exp(-0.5 * dn * dn)
        wn[i] = dn / m1
    return kn, wn, fn


@njit(cache=True)
def normals_from_bits(raw: np.ndarray, out: np.ndarray, kn: np.ndarray, wn: np.ndarray,
                      fn: np.ndarray) -> int:  # pragma: no cover (compiled)
    """Fill ``out`` (float32) with standard normals made from the 64-bit words ``raw`` by
    the ziggurat method (Marsaglia and Tsang 2000). Word ``i`` gives ``out[i]``'s first
    try (a signed 32-bit value and, from other bits, the layer); the few tries that fall
    outside their layer's rectangle are redone in order with the words after
    ``out.size`` (the tail and wedge tests take one more word each). Returns how many
    words were used, or -1 if ``raw`` ran out (the caller supplies more words)."""
    tail = 3.442619855899
    inv32 = 1.0 / 4294967296.0
    n = out.size
    nraw = raw.size
    if nraw < n:
        return -1
    redo = np.empty(n, dtype=np.bool_)
    low = np.uint64(0xFFFFFFFF)
    sh = np.uint64(32)
    m7 = np.uint64(127)
    for i in range(n):  # the common case, without branches
        bits = raw[i]
        hz = np.int64(bits & low) - 2147483648
        iz = np.int64((bits >> sh) & m7)
        out[i] = hz * wn[iz]
        redo[i] = abs(hz) >= kn[iz]
    k = n
    for i in range(n):
        if not redo[i]:
            continue
        bits = raw[i]
        while True:
            hz = np.int64(bits & low) - 2147483648
            iz = np.int64((bits >> sh) & m7)
            x = hz * wn[iz]
            if abs(hz) < kn[iz]:
                break
            if k >= nraw:
                return -1
            extra = raw[k]
            k += 1
            u1 = (np.float64(extra & low) + 0.5) * inv32
            u2 = (np.float64(extra >> sh) + 0.5) * inv32
            if iz == 0:  # the tail beyond the base strip: draw from it until accepted
                x = -math.log(u1) / tail
                while -2.0 * math.log(u2) < x * x:
                    if k >= nraw:
                        return -1
                    extra = raw[k]
                    k += 1
                    x = -math.log((np.float64(extra & low) + 0.5) * inv32) / tail
                    u2 = (np.float64(extra >> sh) + 0.5) * inv32
                x = tail + x if hz > 0 else -tail - x
                break
            if fn[iz] + u1 * (fn[iz - 1] - fn[iz]) < math.exp(-0.5 * x * x):
                break
            if k >= nraw:
                return -1
            bits = raw[k]
            k += 1
        out[i] = x
    return k
