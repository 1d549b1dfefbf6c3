"""Checked sensor inputs of the particle filter: range scans (shared by its two scan
models) and position / heading fixes as the compiled weighting reads them."""

from __future__ import annotations

import math

import numpy as np

from estimators.mcl._team_kernels import FIX_COLUMNS

__all__ = ["check_scan", "fix_parameters"]


def check_scan(ranges: np.ndarray, angles: np.ndarray, max_range: float, angles_ok: bytes
               ) -> tuple[np.ndarray, np.ndarray, float, float, bytes]:
    """Validated 1D ``ranges`` and ``angles`` (ranges may exceed ``max_range``), the
    checked ``max_range`` and the largest range (``-inf`` for an empty scan).

    ``angles_ok``: the bytes of the beam angles last found finite (scanners repeat their
    angles, so they are checked once); returned updated.
    """
    ranges = np.asarray(ranges, dtype=float)
    angles = np.asarray(angles, dtype=float)
    if ranges.ndim != 1:
        ranges = ranges.ravel()
        angles = angles.ravel()
    if ranges.shape != angles.shape:
        raise ValueError(f"ranges {ranges.shape} and angles {angles.shape} must match")
    max_range = float(max_range)
    if not (math.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be a positive finite number, got {max_range}")
    hi = -math.inf
    if ranges.size:
        if ranges.size <= 64:  # small scans: cheaper in Python than three reductions
            rl = ranges.tolist()
            total = sum(rl)  # NaN when any range is
            lo, hi = min(rl), max(rl)
        else:
            total = lo = float(ranges.min())
            hi = float(ranges.max())
        if not (lo >= 0 and total == total):
            raise ValueError(f"ranges must be >= 0 and not NaN, got {ranges}")
        key = angles.tobytes()  # scanners repeat their angles: check them once
        if key != angles_ok:
            if not math.isfinite(angles.sum()):
                raise ValueError(f"beam angles must be finite, got {angles}")
            angles_ok = key
    return ranges, angles, max_range, hi, angles_ok


def fix_parameters(origin: np.ndarray, xy: np.ndarray | None = None, xy_var: float = 1.0,
                   heading: float | None = None, heading_std: float = 1.0) -> np.ndarray:
    """A position fix ``xy`` (m, variance ``xy_var`` m^2) and / or a heading fix (rad,
    standard deviation ``heading_std``), checked, as
    :func:`~estimators.mcl.weighting.weigh_team` reads them:
    ``[gps?, x, y, -0.5 / xy_var, compass?, heading, -0.5 / heading_std**2]`` with
    positions from ``origin`` ``(3, 1)`` (a :class:`~estimators.mcl.team.ParticleSet`'s)."""
    fix = np.zeros(FIX_COLUMNS)
    if xy is not None:
        t = np.asarray(xy, dtype=float)
        if t.shape != (2,) or not np.all(np.isfinite(t)):
            raise ValueError(f"xy must be 2 finite numbers, got {xy}")
        if not (math.isfinite(xy_var) and xy_var > 0):
            raise ValueError(f"xy_var must be finite and > 0, got {xy_var}")
        org = origin
        fix[:4] = (1.0, t[0] - org[0, 0], t[1] - org[1, 0], -0.5 / xy_var)
    if heading is not None:
        if not math.isfinite(heading):
            raise ValueError(f"heading must be finite, got {heading}")
        if not (math.isfinite(heading_std) and heading_std > 0):
            raise ValueError(f"heading_std must be finite and > 0, got {heading_std}")
        fix[4:] = (1.0, heading, -0.5 / heading_std**2)
    return fix
