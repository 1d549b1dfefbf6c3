"""Density trees: piecewise-constant densities grown from weighted samples.

Fox et al. turn a sample set into a continuous density so that it can be
evaluated at another robot's particles (Koller and Fratkina; Moore et al.;
Omohundro). The root covers a box (the domain); a node is split into two
equally sized halves along its longest (scaled) dimension while it holds more
than ``leaf_size`` samples and is shallower than ``max_depth``. Each leaf's
density is the weight of its samples divided by the total weight and by the
leaf's volume (maximum likelihood for a piecewise-constant density), so the
density integrates to exactly 1 over the domain.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from estimators.mcl._kernels import grow_tree, tree_density

__all__ = ["DensityTree", "load_kernels"]


class DensityTree:
    """A piecewise-constant density over a box, grown from weighted samples.

    Parameters
    ----------
    samples:
        ``(M, d)`` sample points, all inside the domain.
    weights:
        ``(M,)`` non-negative weights with a positive sum (default: equal).
    low, high:
        Domain corners ``(d,)``; default: the samples' bounding box, widened by
        1e-9 of its size (and by 1e-9 where it is flat) so that every sample
        lies strictly inside. A sample outside ``[low, high)`` raises.
    scale:
        ``(d,)`` factors applied to extents when choosing the longest
        dimension (e.g. metres per radian for a heading axis); default ones.
    leaf_size:
        A node with more samples than this is split; default
        ``max(10, ceil(sqrt(M)))`` (the rule of thumb of Thrun et al.).
    max_depth:
        Depth limit (root has depth 0); default 24.
    """

    def __init__(
        self,
        samples: np.ndarray,
        weights: np.ndarray | None = None,
        low: np.ndarray | None = None,
        high: np.ndarray | None = None,
        scale: np.ndarray | None = None,
        leaf_size: int | None = None,
        max_depth: int = 24,
    ) -> None:
        x = np.asarray(samples, dtype=float)
        if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
            raise ValueError(f"samples must have shape (M>=1, d>=1), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("samples must be finite")
        m, d = x.shape
        if weights is None:
            w = np.full(m, 1.0 / m)
        else:
            w = np.asarray(weights, dtype=float)
            if w.shape != (m,):
                raise ValueError(f"weights must have shape ({m},), got {w.shape}")
            total = w.sum()
            if not np.all(np.isfinite(w)) or w.min() < 0 or total <= 0:
                raise ValueError(f"weights must be finite, non-negative, with a positive sum; "
                                 f"got sum={total}")
            w = w / total
        if low is None or high is None:
            lo_s, hi_s = x.min(axis=0), x.max(axis=0)
            span = np.where(hi_s > lo_s, hi_s - lo_s, 1.0)
        lo = lo_s - 1e-9 * span if low is None else np.asarray(low, dtype=float)
        hi = hi_s + 1e-9 * span if high is None else np.asarray(high, dtype=float)
        if lo.shape != (d,) or hi.shape != (d,):
            raise ValueError(f"low and high must have shape ({d},), got {lo.shape}, {hi.shape}")
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ValueError(f"domain must be finite with high > low, got low={lo}, high={hi}")
        outside = ~np.all((x >= lo) & (x < hi), axis=1)
        if outside.any():
            raise ValueError(f"{int(outside.sum())} samples lie outside the domain "
                             f"[{lo.tolist()}, {hi.tolist()})")
        sc = np.ones(d) if scale is None else np.asarray(scale, dtype=float)
        if sc.shape != (d,) or not np.all(np.isfinite(sc)) or np.any(sc <= 0):
            raise ValueError(f"scale must be {d} positive numbers, got {scale}")
        if leaf_size is None:
            leaf_size = max(10, int(np.ceil(np.sqrt(m))))
        if leaf_size < 1:
            raise ValueError(f"leaf_size must be >= 1, got {leaf_size}")
        if max_depth < 0:
            raise ValueError(f"max_depth must be >= 0, got {max_depth}")
        self.dim = d
        self.low = lo
        self.high = hi
        self.n_samples = m
        self._build(x, w, sc, int(leaf_size), int(max_depth))

    def _build(self, x: np.ndarray, w: np.ndarray, scale: np.ndarray, leaf_size: int,
               max_depth: int) -> None:
        """Grow the tree breadth first, level by level, in one compiled pass
        (:func:`estimators.mcl._kernels.grow_tree`); a node's children are consecutive."""
        lo, hi, dim, val, left, mass, depth = grow_tree(
            np.ascontiguousarray(x), w, self.low, self.high, scale, leaf_size, max_depth)
        self._lo = lo
        self._hi = hi
        self._split_dim = dim
        self._split_val = val
        self._left = left
        self._right = np.where(left >= 0, left + 1, -1)
        self._mass = mass
        volume = np.prod(hi - lo, axis=1)
        self._is_leaf = left < 0
        self._density = np.where(self._is_leaf, mass / volume, 0.0)
        self.depth = int(depth)

    @property
    def n_leaves(self) -> int:
        """Number of leaves."""
        return int(self._is_leaf.sum())

    def leaves(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Leaf boxes and densities: ``(low (L, d), high (L, d), density (L,))``."""
        m = self._is_leaf
        return self._lo[m].copy(), self._hi[m].copy(), self._density[m].copy()

    def integral(self) -> float:
        """Sum over leaves of density times volume (1 up to rounding)."""
        lo, hi, dens = self.leaves()
        return float(np.sum(dens * np.prod(hi - lo, axis=1)))

    @property
    def volume(self) -> float:
        """Volume of the domain box."""
        return float(np.prod(self.high - self.low))

    def pdf(self, points: np.ndarray) -> np.ndarray:
        """Density at ``points`` ``(..., d)``; 0 outside the domain ``[low, high)``."""
        p = np.asarray(points, dtype=float)
        if p.shape[-1:] != (self.dim,):
            raise ValueError(f"points must have a trailing axis of {self.dim}, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise ValueError("points must be finite")
        flat = np.ascontiguousarray(p.reshape(-1, self.dim))
        out = tree_density(flat, self.low, self.high, self._split_dim, self._split_val,
                           self._left, self._density)
        return out.reshape(p.shape[:-1])


@cache
def load_kernels() -> None:
    """Load the compiled tree kernels now (from numba's disk cache, compiling them the
    first time): otherwise the first tree of a process pays it, about 10 ms (an env step
    with the first robot detection would stall). Does nothing after the first call."""
    DensityTree(np.array([[0.0], [1.0]])).pdf(np.array([[0.5]]))
