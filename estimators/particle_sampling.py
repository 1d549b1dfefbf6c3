"""Resampling helpers of the particle filter: low-variance (systematic) resampling
and the KLD-sampling bound (Fox 2003) on the number of particles."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.special import ndtri

__all__ = ["kld_need", "kld_sample_bound", "low_variance_from_cumulative", "low_variance_indices"]


def low_variance_indices(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Low-variance (systematic) resampling: ``n`` sorted indices drawn in proportion to weights.

    One uniform offset ``u``, ``n`` equally spaced pointers ``(u + j) / n`` of the
    cumulative weight; particle ``i`` is copied once per pointer that falls in
    its cumulative interval. O(n + len(weights)) via ``np.repeat``.
    ``weights`` must be non-negative with a positive finite sum.
    """
    weights = np.asarray(weights, dtype=float)
    if weights.ndim != 1 or weights.size == 0:
        raise ValueError(f"weights must be a non-empty 1D array, got shape {weights.shape}")
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    cum = np.add.accumulate(weights)
    total = cum[-1]
    if not np.isfinite(total) or total <= 0 or weights.min() < 0:
        raise ValueError(
            f"weights must be non-negative with a positive finite sum, got sum={total}"
        )
    return low_variance_from_cumulative(cum, n, rng)


def low_variance_from_cumulative(cum: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Core of :func:`low_variance_indices` from the cumulative weights (no checks)."""
    total = cum[-1]
    u = rng.random()
    # number of pointers strictly below each cumulative weight (rounding may push
    # it past n, which no pointer sees)
    below = cum * (n / total)
    below -= u
    np.ceil(below, out=below)  # >= 0 since u < 1
    below_i = below.astype(np.intp)
    below_i[-1] = n
    # pointer j goes to the number of particles whose interval ends at or before it
    return np.add.accumulate(np.bincount(below_i, minlength=n + 1)[:n])


def kld_sample_bound(k: np.ndarray, epsilon: float, delta: float) -> np.ndarray:
    """Samples needed for KLD-sampling with ``k`` occupied bins (Fox 2003, Wilson-Hilferty).

    ``n = (k-1)/(2 eps) * (1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) z_{1-delta})^3``;
    1 for ``k <= 1``.
    """
    k = np.asarray(k, dtype=float)
    z = ndtri(1.0 - delta)
    km1 = np.maximum(k - 1.0, 1.0)
    a = 2.0 / (9.0 * km1)
    n = km1 / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3
    return np.where(k <= 1, 1.0, np.ceil(n))


@lru_cache(maxsize=32)
def kld_need(epsilon: float, delta: float, n_min: int, n_max: int) -> np.ndarray:
    """``max(kld_sample_bound(k), n_min)`` for ``k = 0 .. n_max`` (read-only, cached)."""
    need = np.maximum(kld_sample_bound(np.arange(n_max + 1), epsilon, delta), n_min)
    need.flags.writeable = False
    return need
