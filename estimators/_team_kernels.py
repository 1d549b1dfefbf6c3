"""Compiled loops (numba, cached on disk) over a team's particle sets in one flat array.

The "block layout": robot ``r``'s particles ``start_r .. end_r - 1`` (``end_r =
ends[r]``, ``start_r`` the previous end) have their float32 ``x, y, heading``
rows stored as one C-ordered ``(3, n_r)`` block at offset ``3 * start_r`` of a
flat array, so each filter's ``(3, n_r)`` state is a contiguous view of the team
array and one call updates every robot. Weights and other per-particle values
are flat ``(N,)`` arrays. Private helpers of :mod:`estimators.mcl_batch` and
:class:`estimators.particle_filter.ParticleFilter`; inputs are checked there.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["predict_blocks", "weigh_blocks"]

# fix columns of weigh_blocks: [gps?, gx, gy, -0.5 / var, compass?, heading, -0.5 / std**2]
FIX_COLUMNS = 7


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
def weigh_blocks(
    flat: np.ndarray, ends: np.ndarray, w_prev: np.ndarray,
    table: np.ndarray, nxp: int, offset: int, pad: np.float32, inv_res: np.float32,
    lo_x: np.float32, lo_y: np.float32, hi_x: np.float32, hi_y: np.float32,
    ux: np.ndarray, uy: np.ndarray, nb: np.ndarray, power: float, fix: np.ndarray,
    loglik: np.ndarray, w: np.ndarray, cum: np.ndarray, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Weight every robot's particles by its laser scan (likelihood field) and fixes.

    Robot ``r`` with ``nb[r] >= 0`` has a scan of ``nb[r]`` endpoints: ``ux[r, b],
    uy[r, b]`` (float32, cells) in its frame. Each particle's scan score is the
    float32 sum, in this order, of the field's penalty at its own cell and the
    field at its endpoints (as :func:`estimators.likelihood_field.lf_loglik`
    computes it), ``loglik = power * score`` (float64). ``fix[r]`` adds a DGPS
    position factor ``exp(-0.5 |p - g|^2 / var) + 1e-12`` and a compass factor
    ``exp(-0.5 e^2 / std^2) + 1e-12`` (``e`` the wrapped heading error) when
    their flags are set. A robot with neither keeps ``w_prev``.

    Writes the normalized weights ``w``, their cumulative sums per robot ``cum``
    and ``out[r] = (log sum w_prev exp(loglik - m) + m, ess, ok)``, the scan's
    log evidence less the field's constant (``nan`` without a scan), the
    effective sample size and 1, or 0 where the weights underflowed (``w``
    then holds garbage for that robot and the caller redoes it).
    """
    two_pi = 2.0 * math.pi
    start = 0
    for r in range(ends.size):
        end = ends[r]
        n = end - start
        base = 3 * start
        scan = nb[r] >= 0
        gps = fix[r, 0] != 0.0
        compass = fix[r, 4] != 0.0
        m = 0.0
        if scan:
            m = -np.inf
            for j in range(n):
                x = min(max(flat[base + j], lo_x), hi_x) * inv_res + pad
                y = min(max(flat[base + n + j], lo_y), hi_y) * inv_res + pad
                h = flat[base + 2 * n + j]
                c = math.cos(h)
                s = math.sin(h)
                acc = table[offset + int(np.rint(y)) * nxp + int(np.rint(x))]
                for b in range(nb[r]):
                    ex = x + c * ux[r, b] - s * uy[r, b]
                    ey = y + s * ux[r, b] + c * uy[r, b]
                    acc += table[int(np.rint(ey)) * nxp + int(np.rint(ex))]
                v = power * np.float64(acc)
                loglik[start + j] = v
                m = max(m, v)
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
                a *= math.exp(loglik[i] - m)
            sum1 += a
            if gps:
                dx = flat[base + j] - gx
                dy = flat[base + n + j] - gy
                a *= math.exp(gc * (dx * dx + dy * dy)) + 1e-12
            if compass:
                e = flat[base + 2 * n + j] - ch
                e -= two_pi * np.rint(e / two_pi)
                a *= math.exp(cc * e * e) + 1e-12
            w[i] = a
            sum2 += a
        ok = sum2 > 0.0 and sum2 < np.inf and sum1 > 0.0
        out[r, 0] = m + math.log(sum1) if scan and ok else np.nan
        out[r, 2] = 1.0 if ok else 0.0
        if ok:
            inv = 1.0 / sum2
            acc2 = 0.0
            sq = 0.0
            for i in range(start, end):
                wi = w[i] * inv
                w[i] = wi
                acc2 += wi
                cum[i] = acc2
                sq += wi * wi
            out[r, 1] = 1.0 / sq
        start = end
