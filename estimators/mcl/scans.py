"""Checks of a range scan's input shared by the particle filter's sensor models."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["check_scan"]


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

