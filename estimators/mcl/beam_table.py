"""Beam-model expected ranges and log-likelihoods from tables computed once per map.

A beam model (:meth:`ParticleFilter.update_beam`) needs, for every particle and
beam, the range a ray cast in the map would return. :class:`RangeTable` holds,
for every cell centre of an :class:`~estimators.mcl.occupancy.OccupancyGrid` and
every one of ``n_bins`` heading bins, the ray-cast range (the nearest of
``rays_per_cone`` rays over a cone when the beam is wide) together with its
first derivatives with respect to the origin's position and the beam's
direction (from the face of the cell the ray hits: a ray that ends on the
vertical face ``x = X`` has range ``(X - x) / cos(phi)``). A lookup corrects the
cell-centre range to the particle's exact position and heading to first order,
which removes most of the error of quantizing poses to cells and bins
(figures in ``tests/estimators/mcl/test_beam_table.py`` and :func:`table_error`).

:class:`BeamLUT` tabulates the beam model's per-beam log-likelihood (tempered
by ``likelihood_exponent``) over quantized measured and expected ranges, so a
scan update is two gathers and a sum per particle.

Tables live in module-level caches keyed by the grid's bytes and the model's
parameters: every filter, robot and env that uses an equal map shares one
table, and a new episode on the same layout builds nothing.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from typing import NamedTuple

import numpy as np
from scipy.special import ndtr

from estimators.mcl._kernels import beam_loglik
from estimators.mcl.occupancy import OccupancyGrid

__all__ = [
    "BeamLUT", "RangeTable", "beam_lut", "beam_probability", "range_table", "scan_loglik",
    "table_error",
]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_MAX_SLOPE = 32.0  # |d range / d position| kept below this (incidence under ~88 degrees)
_CACHE_SIZE = 16
_TABLES: OrderedDict[tuple, RangeTable] = OrderedDict()
_LUTS: OrderedDict[tuple, BeamLUT] = OrderedDict()


def _grid_key(grid: OccupancyGrid) -> tuple:
    occ = np.ascontiguousarray(grid.occupied)
    digest = hashlib.blake2b(occ.tobytes(), digest_size=16).digest()
    return occ.shape, digest, float(grid.resolution), tuple(float(v) for v in grid.origin)


MAX_SLOPE = _MAX_SLOPE  # the clip of a table's position derivatives (public name)


def table_key(grid: OccupancyGrid, max_range: float, n_bins: int, cone_half_width: float,
              rays_per_cone: int) -> tuple:
    """The key :func:`range_table` caches ``grid``'s table under for these parameters."""
    rays = int(rays_per_cone) if cone_half_width > 0 else 1
    cone = float(cone_half_width) if rays > 1 else 0.0
    return (*_grid_key(grid), float(max_range), int(n_bins), cone, rays)


def cached_table(key: tuple) -> RangeTable | None:
    """The table cached under ``key`` (:func:`table_key`), or ``None``."""
    return _TABLES.get(key)


def remember_table(key: tuple, table: RangeTable) -> None:
    """Cache ``table`` under ``key`` (:func:`table_key`), for :func:`range_table` to return:
    for a table built elsewhere (:mod:`estimators.mcl.range_cast`)."""
    _remember(_TABLES, key, table)


def _remember(cache: OrderedDict, key: tuple, value: object) -> None:
    cache[key] = value
    while len(cache) > _CACHE_SIZE:
        cache.popitem(last=False)


class RangeTable(NamedTuple):
    """Ray-cast ranges and their derivatives per cell centre and heading bin (see module doc).

    ``rows`` is ``(ny * nx * n_bins, 4)`` int16, in units of ``scales``: range (m)
    from the cell centre along the bin's central direction
    ``-pi + (k + 0.5) * 2 pi / n_bins``, then its derivatives by the origin's
    ``x`` and ``y`` (m / m) and by the direction (m / rad). Occupied cells hold
    zeros. (16-bit rows halve the memory a lookup reads; the quantization is
    ``max_range / 32767`` for ranges, far below any beam noise.)
    """

    rows: np.ndarray
    n_bins: int
    nx: int
    ny: int
    resolution: float
    origin: tuple[float, float]
    max_range: float
    cone_half_width: float
    rays_per_cone: int
    free_cells: np.ndarray  # (ny * nx,) bool: the map's free cells
    scales: np.ndarray  # (4,) float32: a row's int16 values times these give the floats

    def expected(self, x: np.ndarray, y: np.ndarray, heading: np.ndarray,
                 angles: np.ndarray) -> np.ndarray:
        """Expected ranges ``(N, B)`` float32 at positions ``x, y`` (m, measured from the
        centre of cell ``(0, 0)``), headings ``(N,)`` and robot-frame beam ``angles (B,)``.

        Positions outside the map read 0 (as inside a wall).
        """
        res = self.resolution
        inv = np.float32(1.0 / res)
        ux = np.multiply(x, inv, dtype=np.float32)
        uy = np.multiply(y, inv, dtype=np.float32)
        np.rint(ux, out=ux)
        np.rint(uy, out=uy)
        ix = ux.astype(np.intp)
        iy = uy.astype(np.intp)
        dx = x - ux * np.float32(res)  # offset from the cell centre (m)
        dy = y - uy * np.float32(res)
        inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        cell = iy * self.nx + ix
        cell[~inside] = 0
        bins = self.n_bins
        scale = np.float32(bins / (2.0 * math.pi))
        hb = np.multiply(heading, scale, dtype=np.float32)
        hb += np.float32(bins / 2)
        kf = hb[:, None] + (np.asarray(angles, dtype=np.float32) * scale)[None, :]
        k = np.floor(kf)
        kf -= k
        kf -= np.float32(0.5)
        kf *= np.float32(1.0 / scale)  # direction minus the bin's centre (rad)
        ki = k.astype(np.intp)
        if bins & (bins - 1) == 0:
            ki &= bins - 1
        else:
            np.remainder(ki, bins, out=ki)
        ki += (cell * bins)[:, None]
        rows = self.rows[ki].astype(np.float32)  # (N, B, 4)
        rows *= self.scales
        r = rows[..., 0]
        r += rows[..., 1] * dx[:, None]
        r += rows[..., 2] * dy[:, None]
        r += rows[..., 3] * kf
        np.clip(r, 0.0, self.max_range, out=r)
        r[~inside] = 0.0
        return r

    def free(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether positions (m from the centre of cell ``(0, 0)``) lie in a free map cell."""
        inv = 1.0 / self.resolution
        ix = np.rint(np.multiply(x, inv, dtype=np.float32)).astype(np.intp)
        iy = np.rint(np.multiply(y, inv, dtype=np.float32)).astype(np.intp)
        inside = (ix >= 0) & (ix < self.nx) & (iy >= 0) & (iy < self.ny)
        cell = np.where(inside, iy * self.nx + ix, 0)
        return inside & self.free_cells[cell]


def _build(grid: OccupancyGrid, max_range: float, n_bins: int, cone: float, rays: int
           ) -> RangeTable:
    """Cast the table's rays from every free cell centre and derive the corrections.

    The position derivatives are clipped to +-``_MAX_SLOPE``: rays that graze a
    wall need steep ones (clipping them at 4 left the hallway's 99th-percentile
    error at 0.38 m instead of 0.14 m).
    """
    ny, nx = grid.shape
    res = grid.resolution
    ox0, oy0 = grid.origin
    occ = grid.occupied
    free = np.flatnonzero(~occ.ravel())
    centres = (np.column_stack([free % nx, free // nx]) + 0.5) * res + np.array([ox0, oy0])
    bw = 2.0 * math.pi / n_bins
    phi = -math.pi + (np.arange(n_bins) + 0.5) * bw
    offsets = np.linspace(-cone, cone, rays) if rays > 1 and cone > 0 else np.zeros(1)
    rows = np.zeros((ny * nx, n_bins, 4), dtype=np.float32)
    shifts = offsets / bw
    on_bins = bool(np.all(np.abs(shifts - np.rint(shifts)) < 1e-9))
    # Cone rays that fall on other bins' centres reuse those bins' rays (one cast per bin)
    cast_offsets = np.zeros(1) if on_bins else offsets
    per = max(1, 400_000 // (n_bins * cast_offsets.size))
    ox, oy = ox0, oy0
    for start in range(0, free.size, per):
        c = centres[start:start + per]
        ang = np.broadcast_to(phi[None, :, None] + cast_offsets[None, None, :],
                              (c.shape[0], n_bins, cast_offsets.size))
        r = grid.cast_rays(c[:, None, None, :], ang, max_range)  # (C, bins, rays)
        if on_bins:  # ray k + s of the single-ray table is the cone's ray at offset s
            idx = (np.arange(n_bins)[:, None] + np.rint(shifts).astype(np.intp)) % n_bins
            r = r[:, idx, 0]
            ang = np.broadcast_to(phi[idx], r.shape)
        j = r.argmin(axis=2)
        r = np.take_along_axis(r, j[..., None], axis=2)[..., 0]
        a = np.take_along_axis(ang, j[..., None], axis=2)[..., 0]
        cos, sin = np.cos(a), np.sin(a)
        # hit point in cell units: a ray stops just past the face it reaches
        hx = (c[:, 0, None] + r * cos - ox) / res
        hy = (c[:, 1, None] + r * sin - oy) / res
        on_x = np.abs(hx - np.rint(hx)) < 1e-3  # a vertical face x = X
        on_y = np.abs(hy - np.rint(hy)) < 1e-3
        hit = (r > 0) & (r < max_range)
        vert = hit & on_x & (~on_y | (np.abs(cos) > np.abs(sin)))
        horiz = hit & on_y & ~vert
        with np.errstate(divide="ignore", invalid="ignore"):
            gx = np.where(vert, -1.0 / cos, 0.0)
            gy = np.where(horiz, -1.0 / sin, 0.0)
            gphi = np.where(vert, r * sin / cos, np.where(horiz, -r * cos / sin, 0.0))
        gx = np.clip(gx, -_MAX_SLOPE, _MAX_SLOPE)
        gy = np.clip(gy, -_MAX_SLOPE, _MAX_SLOPE)
        gphi = np.clip(gphi, -_MAX_SLOPE * r, _MAX_SLOPE * r)
        block = rows[free[start:start + per]]
        block[..., 0], block[..., 1], block[..., 2], block[..., 3] = r, gx, gy, gphi
        rows[free[start:start + per]] = block
    scales = (np.array([1.0, _MAX_SLOPE, _MAX_SLOPE, _MAX_SLOPE * max_range]) / 32767.0)
    scales[0] *= max_range
    flat = np.rint(rows.reshape(-1, 4) / scales).astype(np.int16)
    flat.flags.writeable = False
    scales = scales.astype(np.float32)
    scales.flags.writeable = False
    free_cells = ~occ.ravel()
    free_cells.flags.writeable = False
    return RangeTable(flat, n_bins, nx, ny, float(res),
                      (float(ox + 0.5 * res), float(oy + 0.5 * res)), float(max_range),
                      float(cone), int(offsets.size), free_cells, scales)


def range_table(grid: OccupancyGrid, max_range: float, n_bins: int = 256,
                cone_half_width: float = 0.0, rays_per_cone: int = 1) -> RangeTable:
    """The :class:`RangeTable` of ``grid`` for these beam parameters (built once, cached).

    A cone (``cone_half_width`` > 0) expects the nearest of ``rays_per_cone`` rays
    spread evenly over it, as :meth:`ParticleFilter.expected_ranges` does.
    """
    if n_bins < 4:
        raise ValueError(f"n_bins must be >= 4, got {n_bins}")
    if not math.isfinite(max_range) or max_range <= 0:
        raise ValueError(f"max_range must be a positive finite number, got {max_range}")
    if not math.isfinite(cone_half_width) or cone_half_width < 0:
        raise ValueError(f"cone_half_width must be finite and >= 0, got {cone_half_width}")
    rays = int(rays_per_cone) if cone_half_width > 0 else 1
    if rays < 1:
        raise ValueError(f"rays_per_cone must be >= 1, got {rays_per_cone}")
    cone = float(cone_half_width) if rays > 1 else 0.0
    key = (*_grid_key(grid), float(max_range), int(n_bins), cone, rays)
    table = _TABLES.get(key)
    if table is None:
        table = _build(grid, float(max_range), int(n_bins), cone, rays)
        _remember(_TABLES, key, table)
    else:
        _TABLES.move_to_end(key)
    return table


def table_error(grid: OccupancyGrid, table: RangeTable, n: int = 20000, seed: int = 0
                ) -> np.ndarray:
    """Absolute errors (m) of table lookups against exact ray casts at ``n`` random free poses.

    One random beam direction per pose; with a cone, the exact value is the
    nearest of the cone's rays cast from the exact pose.
    """
    rng = np.random.default_rng(seed)
    xy = grid.sample_free(n, rng)
    th = rng.uniform(-math.pi, math.pi, n)
    offsets = (np.linspace(-table.cone_half_width, table.cone_half_width, table.rays_per_cone)
               if table.rays_per_cone > 1 else np.zeros(1))
    exact = grid.cast_rays(xy[:, None, :], th[:, None] + offsets[None, :],
                           table.max_range).min(axis=1)
    sx = (xy[:, 0] - table.origin[0]).astype(np.float32)
    sy = (xy[:, 1] - table.origin[1]).astype(np.float32)
    got = table.expected(sx, sy, th.astype(np.float32), np.zeros(1))[:, 0]
    return np.abs(got - exact)


class BeamLUT(NamedTuple):
    """Tempered per-beam beam-model log-likelihoods over quantized ranges.

    ``table`` is ``((L + 1) * L,)`` float32: entry ``zq * L + eq`` is
    ``exponent * log p(z | z_exp)`` for a measured range ``zq * step`` and an
    expected range ``eq * step`` (``L = levels``, ``step = max_range / (L - 1)``);
    row ``L - 1`` is a max-range reading and row ``L`` is all zeros (a beam
    with no reading).
    """

    table: np.ndarray
    levels: int
    step: float
    max_range: float

    def rows(self, z: np.ndarray) -> np.ndarray:
        """Row offsets (intp) of measured ranges ``z``; NaN (no reading) selects the zero row."""
        z = np.asarray(z, dtype=float)
        lv = self.levels
        q = np.full(z.shape, lv, dtype=np.intp)
        ok = ~np.isnan(z)
        zq = np.minimum(np.rint(np.minimum(z[ok], self.max_range) / self.step), lv - 2)
        zq[z[ok] >= self.max_range] = lv - 1
        q[ok] = zq.astype(np.intp)
        return q * lv

    def loglik(self, expected: np.ndarray, row_offsets: np.ndarray) -> np.ndarray:
        """Sum over beams ``(N,)`` for expected ranges ``(N, B)`` and row offsets ``(B,)`` or
        ``(N, B)``. Accumulated in float64, which adds a few dozen float32 terms exactly
        unless their magnitudes differ by more than ~2**25: skipped beams (zero rows) then
        leave the result unchanged."""
        q = np.multiply(expected, np.float32(1.0 / self.step), dtype=np.float32)
        q += np.float32(0.5)
        idx = q.astype(np.intp)
        idx += row_offsets
        return self.table.take(idx).sum(axis=1, dtype=np.float64)


def scan_loglik(table: RangeTable, lut: BeamLUT, flat: np.ndarray, angles: np.ndarray,
                row_offsets: np.ndarray, ends: np.ndarray, occupied_loglik: float) -> np.ndarray:
    """Beam-model scan log-likelihoods ``(N,)`` of particle sets stored back to back.

    ``flat`` holds the float32 ``x, y`` (m from the centre of cell ``(0, 0)``) and
    headings of robot ``r``'s particles, which end (exclusive) at ``ends[r]``, as one
    ``(3, n_r)`` block (the block layout of :mod:`estimators.mcl._team_kernels`); its
    readings select the likelihood rows ``row_offsets[r]`` (:meth:`BeamLUT.rows`)
    for the beams at robot-frame ``angles``. Equals
    ``lut.loglik(table.expected(...), rows)`` plus ``occupied_loglik`` where
    :meth:`RangeTable.free` is False, in one compiled pass.
    """
    if table.max_range != lut.max_range:
        raise ValueError(f"range table and likelihood table disagree on max_range: "
                         f"{table.max_range} vs {lut.max_range}")
    return beam_loglik(table.rows, table.scales, table.free_cells, table.nx, table.ny,
                       table.resolution, table.n_bins, table.max_range,
                       np.ascontiguousarray(flat, np.float32),
                       np.ascontiguousarray(angles, np.float64), lut.table,
                       1.0 / lut.step, np.ascontiguousarray(row_offsets, np.intp),
                       np.ascontiguousarray(ends, np.intp), float(occupied_loglik))


def beam_lut(max_range: float, sigma: float, z_hit: float, z_short: float, z_max: float,
             z_rand: float, lambda_short: float, exponent: float, levels: int = 512) -> BeamLUT:
    """The :class:`BeamLUT` of a beam model (cached); see :class:`MCLConfig` for the terms."""
    key = (float(max_range), float(sigma), float(z_hit), float(z_short), float(z_max),
           float(z_rand), float(lambda_short), float(exponent), int(levels))
    lut = _LUTS.get(key)
    if lut is not None:
        return lut
    step = max_range / (levels - 1)
    zexp = np.arange(levels) * step
    z = (np.arange(levels) * step)[:, None]
    p = beam_probability(z, zexp[None, :], max_range, sigma, z_hit, z_short, z_max, z_rand,
                         lambda_short)
    table = np.zeros((levels + 1, levels))
    table[:levels] = exponent * np.log(p)
    flat = table.astype(np.float32).ravel()
    flat.flags.writeable = False
    lut = BeamLUT(flat, levels, step, float(max_range))
    _remember(_LUTS, key, lut)
    return lut


def beam_probability(z: np.ndarray, zexp: np.ndarray, max_range: float, sigma: float,
                     z_hit: float, z_short: float, z_max: float, z_rand: float,
                     lambda_short: float) -> np.ndarray:
    """Beam-model density of measured ranges ``z`` given expected ranges ``zexp`` (broadcast).

    Gaussian hit (truncated to ``[0, max_range]``), exponential short readings,
    a point mass at ``max_range`` and a uniform floor.
    """
    is_max = z >= max_range
    norm = ndtr((max_range - zexp) / sigma) - ndtr(-zexp / sigma)
    p_hit = np.exp(-0.5 * ((z - zexp) / sigma) ** 2 - _LOG_SQRT_2PI) / (
        sigma * np.maximum(norm, 1e-12)
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        short_norm = 1.0 - np.exp(-lambda_short * zexp)
        p_short = np.where(
            (z <= zexp) & (short_norm > 0), lambda_short * np.exp(-lambda_short * z) / short_norm,
            0.0,
        )
    return np.where(
        is_max,
        z_max + z_rand / max_range,
        z_hit * p_hit + z_short * p_short + z_rand / max_range,
    )
