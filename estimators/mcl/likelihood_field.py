"""The likelihood-field laser model's table (used by :class:`ParticleFilter`).

:func:`build_lf_field` turns a map and an :class:`~estimators.mcl.config.MCLConfig`
into one flat ``float32`` table; :func:`lf_endpoints` turns a scan into the beam
endpoints the filter's compiled weighting reads
(:func:`estimators.mcl._team_kernels.weigh_blocks`). :func:`lf_loglik` is the same
score in numpy (one matrix product and one gather, with its work arrays from
:func:`beam_matrix` and :func:`lf_buffers`), kept as the reference the compiled
kernel is tested against.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from estimators.mcl.config import MCLConfig
from estimators.mcl.occupancy import OccupancyGrid

__all__ = [
    "LF_POWER", "LFField", "beam_matrix", "beam_units", "build_lf_field", "lf_buffers",
    "lf_endpoints", "lf_loglik",
]

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)
# For float32 0 <= x < 2**23, x + _MAGIC rounds x to an integer k (ties to even) and
# has the bits _MAGIC_BITS + k. The likelihood table's width w has w + 1 divisible by
# 256, which makes _MAGIC_BITS * (w + 1) vanish modulo 2**32 (_MAGIC_BITS = 75 * 2**24).
_MAGIC = np.float32(2**23)
_MAGIC_BITS = int(np.array(_MAGIC).view(np.int32))
assert _MAGIC_BITS * 256 % 2**32 == 0
# The likelihood-field table holds log-likelihoods divided by this: a scan's sum then
# stays within float32 exp's range for common scans (powered back in float64).
LF_POWER = 4
_UNITS: dict[tuple[bytes, float], tuple[np.ndarray, np.ndarray]] = {}  # beam directions


class LFField(NamedTuple):
    """The likelihood-field tables of one map, model and maximum range."""

    table: np.ndarray  # flat float32: [log-likelihood grid | penalty grid]
    pad: int  # border cells around the map
    nxp: int  # padded grid width
    nyp: int  # padded grid height
    offset: int  # start of the penalty grid in ``table``
    lo: np.ndarray  # (2, 1) float32: lowest allowed particle position (state coordinates)
    hi: np.ndarray  # (2, 1) float32: highest allowed particle position (state coordinates)
    inv_res: float  # 1 / resolution
    reach: float  # ranges are clipped to this (no endpoint can leave the table)
    magic: np.float32  # 2**23 + pad: rounds cell coordinates, adds the pad (see _MAGIC)
    lmax: float  # the log-likelihood grid holds (exponent * log(p) - lmax) / LF_POWER
    span: float  # lmax minus the least exponent * log(p)


def build_lf_field(grid: OccupancyGrid, cfg: MCLConfig, max_range: float) -> LFField:
    """Tables gathered by the likelihood-field update for ``max_range``.

    One flat ``float32`` array holds two grids of the same padded geometry
    (a border of ``pad`` cells, ``pad >= reach / resolution``, so every
    beam endpoint of a particle inside the map lands inside the grid):
    first the tempered per-beam log-likelihood
    ``exponent * log(z_hit N(d) + z_rand / max_range)`` less its maximum
    ``lmax`` (so a scan's sum is at most 0), then the position log-penalty
    (0 in free map cells, ``occupied_loglik`` in occupied or outside cells),
    both divided by ``LF_POWER``.
    """
    res = grid.resolution
    xmin, ymin, xmax, ymax = grid.bounds
    # Beyond the map's diagonal plus lf_max_dist every endpoint scores the
    # floor value, so longer ranges are clipped to ``reach`` (bounds the pad).
    reach = min(max_range, math.hypot(xmax - xmin, ymax - ymin) + cfg.lf_max_dist)
    pad = int(np.ceil(reach / res)) + 2
    dist = np.minimum(grid.distance_field(pad), cfg.lf_max_dist)
    lik = cfg.lf_z_hit * np.exp(-0.5 * (dist / cfg.lf_sigma) ** 2 - _LOG_SQRT_2PI) / (
        cfg.lf_sigma
    ) + cfg.lf_z_rand / max_range
    loglik = cfg.likelihood_exponent * np.log(lik)
    lmax = float(loglik.max())
    span = lmax - float(loglik.min())
    loglik = (loglik - lmax) / LF_POWER
    inside = np.pad(~grid.occupied, pad, constant_values=False)
    # Widen to w with w + 1 divisible by 256 (see _MAGIC); the extra columns on
    # the right are never gathered.
    nyp, nxp = dist.shape
    extra = (nxp // 256 + 1) * 256 - 1 - nxp
    loglik = np.pad(loglik, ((0, 0), (0, extra)), mode="edge")
    inside = np.pad(inside, ((0, 0), (0, extra)), constant_values=False)
    nxp += extra
    penalty = np.where(inside, 0.0, cfg.occupied_loglik / LF_POWER)
    table = np.concatenate([loglik.ravel(), penalty.ravel()]).astype(np.float32)
    # the centres of the cells next to the map, in state coordinates
    ny, nx = grid.shape
    lo = np.full((2, 1), -res, dtype=np.float32)
    hi = (np.array([[nx], [ny]]) * res).astype(np.float32)
    return LFField(table, pad, nxp, nyp, nxp * nyp, lo, hi, 1.0 / res, reach,
                   np.float32(_MAGIC + pad), lmax, span)


def beam_units(lf: LFField, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float32 unit vectors of the beam ``angles (B,)`` in cells per metre of ``lf``
    (cached by angles and resolution)."""
    key = (angles.tobytes(), lf.inv_res)
    unit = _UNITS.get(key)
    if unit is None:
        if len(_UNITS) > 64:  # scanners repeat their angles: a few entries suffice
            _UNITS.clear()
        unit = _UNITS[key] = (np.cos(angles) * lf.inv_res).astype(np.float32), (
            np.sin(angles) * lf.inv_res).astype(np.float32)
    return unit


def lf_endpoints(lf: LFField, ranges: np.ndarray, angles: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Beam endpoints ``(ux, uy)`` float32 in cells, in the robot frame, of readings
    ``ranges`` (``(..., B)``, below the maximum range; clipped here to ``lf.reach``; NaN
    gives NaN) at ``angles (B,)``: the scan as the compiled weighting
    (:func:`estimators.mcl._team_kernels.weigh_blocks`) reads it, rounded as
    :func:`lf_loglik` rounds it."""
    unit = beam_units(lf, angles)
    r = np.minimum(ranges, lf.reach)
    ux = np.empty(r.shape, dtype=np.float32)
    uy = np.empty(r.shape, dtype=np.float32)
    np.multiply(unit[0], r, out=ux, casting="unsafe")  # in float64, rounded once
    np.multiply(unit[1], r, out=uy, casting="unsafe")
    return ux, uy


def lf_loglik(
    lf: LFField, st: np.ndarray, ranges: np.ndarray, angles: np.ndarray, mats: dict, bufs: dict
) -> np.ndarray:
    """Tempered scan log-likelihood plus position penalty of each particle, over ``LF_POWER``.

    ``st`` is the filter's ``(3, N)`` float32 state; ``ranges`` (already below
    ``max_range`` and clipped to ``lf.reach``) and robot-frame ``angles`` are
    ``(B,)``; ``mats`` and ``bufs`` are the caches of :func:`beam_matrix` and
    :func:`lf_buffers`. The scan's log-likelihood is ``LF_POWER * result +
    B * lf.lmax``; the result (a reused ``(N,)`` float32 buffer) lies between
    ``-(B * lf.span - occupied_loglik) / LF_POWER`` and 0.
    """
    nb = ranges.size
    n = st.shape[1]
    # E = M @ [cos; sin; x; y] gives endpoint cell coordinates: rows ex then ey;
    # rows nb and 2 nb + 1 are the particle itself (they gather the penalty).
    mat, unit, mat_r = beam_matrix(mats, angles, lf)
    np.multiply(unit, ranges, out=mat_r, casting="unsafe")
    a4, cos_h, sin_h, xy, ecell, bits_x, flat, gath, ones, loglik = lf_buffers(bufs, nb, n)
    np.cos(st[2], out=cos_h)
    np.sin(st[2], out=sin_h)
    # Particle positions (metres from the centre of map cell (0, 0)), clamped to
    # one cell around the map so that no endpoint leaves the table (clamped
    # particles sit outside the map and get the penalty anyway).
    np.maximum(st[:2], lf.lo, out=xy)
    np.minimum(xy, lf.hi, out=xy)
    np.matmul(mat, a4, out=ecell)
    # Rounded, these are map cells. Round in place: adding 2**23 + pad leaves the
    # padded cell coordinate in the float32 mantissa, so the int32 view holds
    # _MAGIC_BITS + padded cell; in (_MAGIC_BITS + iy) * nxp + _MAGIC_BITS + ix
    # the constant wraps to 0 in int32.
    ecell += lf.magic
    flat *= lf.nxp  # the y rows
    flat += bits_x
    flat[nb] += lf.offset  # the particle's own cell: the penalty grid
    lf.table.take(flat, out=gath, mode="clip")  # in range by construction; the x
    # rows are spent, so the values go there
    return np.matmul(ones, gath, out=loglik)  # sum over the beams and the penalty


def beam_matrix(
    cache: dict, angles: np.ndarray, lf: LFField
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reusable endpoint matrix of beams at robot-frame ``angles`` for table ``lf``.

    Returns ``(mat, unit, mat_r)``: ``mat`` ``(2 nb + 2, 4)`` float32
    (Fortran order) with its constant columns set (``1 / resolution`` on the
    position columns); ``unit`` ``(2, 2, nb)`` float32 the rotation entries
    in cells per metre of range (columns ``[cos, sin]`` and ``[-sin, cos]``
    of the x and y rows); ``mat_r`` the view of ``mat``'s range-dependent
    entries that ``unit * ranges`` fills (the particle rows keep zeros
    there). Cached by the angles' bytes (scanners repeat their beam angles).
    """
    key = (angles.tobytes(), lf.inv_res)
    bufs = cache.get(key)
    if bufs is None:
        nb = angles.size
        mat = np.zeros((2 * nb + 2, 4), dtype=np.float32, order="F")
        mat[: nb + 1, 2] = lf.inv_res
        mat[nb + 1:, 3] = lf.inv_res
        c, s = np.cos(angles) * lf.inv_res, np.sin(angles) * lf.inv_res
        unit = np.array([[c, s], [-s, c]], dtype=np.float32)
        mat_r = mat[:, :2].T.reshape(2, 2, nb + 1)[:, :, :nb]
        if len(cache) > 64:  # bound the cache (varying max-range dropouts)
            cache.clear()
        bufs = cache[key] = (mat, unit, mat_r)
    return bufs


def lf_buffers(cache: dict, nb: int, n: int) -> tuple[np.ndarray, ...]:
    """Reusable work arrays of the likelihood-field update for ``nb`` beams, ``n`` particles.

    ``(a4, cos_h, sin_h, xy, ecell, bits_x, flat, gath, ones, loglik)``:
    ``a4`` the ``(4, n)`` float32 ``[cos; sin; x; y]`` and views of its
    rows; ``ecell`` the ``(2 nb + 2, n)`` float32
    endpoint cell coordinates, its int32 view split into the ``x`` and
    ``y`` rows, and the float32 ``x`` rows that receive the gathered values;
    ``nb + 1`` ones and an ``(n,)`` float32 array for their sum.
    """
    key = (nb, n)
    bufs = cache.get(key)
    if bufs is None:
        if len(cache) > 8:  # adaptive particle counts vary: keep a few
            cache.clear()
        a4 = np.empty((4, n), dtype=np.float32)
        ecell = np.empty((2 * nb + 2, n), dtype=np.float32)
        bits = ecell.view(np.int32)
        bufs = cache[key] = (
            a4, a4[0], a4[1], a4[2:], ecell, bits[: nb + 1], bits[nb + 1:],
            ecell[: nb + 1], np.ones(nb + 1, dtype=np.float32), np.empty(n, dtype=np.float32),
        )
    return bufs
