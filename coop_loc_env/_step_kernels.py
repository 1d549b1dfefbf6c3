"""Compiled loops (numba, cached on disk) of the env step's hot paths.

Each kernel fuses a chain of elementwise numpy operations into one pass, with
the same IEEE operations in the same order (no fast-math: no reassociation,
no fused multiply-adds), so results are bit-identical to the numpy code they
replace. Trigonometry and matrix products stay in numpy (their vectorized
implementations round differently from a scalar loop's). Private helpers of
:mod:`coop_loc_env.raycast`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["fan_ranges"]


@njit(cache=True, error_model="numpy")
def fan_ranges(
    b: np.ndarray, rel: np.ndarray, r2: np.ndarray, dirs: np.ndarray, pose: np.ndarray,
    box: np.ndarray, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Nearest circle or wall along each ray of equal fans, into ``out`` ``(robots, rays)``.

    ``b`` ``(K, robots, rays)`` holds ``u . (c - o)`` of each candidate circle,
    ``rel`` ``(robots, K, 2)`` the candidates' ``c - o``, ``r2`` ``(robots, K)``
    their squared radii (``-inf``: a slot no ray hits), ``dirs`` ``(2, robots,
    rays)`` the rays' (cos, sin) and ``pose`` ``(robots, 3)`` the fans' poses.
    A ray hits a circle at ``t = b - sqrt(b^2 - q)``, ``q = |c - o|^2 - r^2``;
    the nearest hit is the largest positive ``1 / t`` (``inf`` without one).
    ``box`` is the world box ``(w, h)``, empty for none: the distance is then
    the smaller of that and the distance to the box's walls (NaN propagates).
    """
    n_k, n_fans, n_rays = b.shape
    inv = np.empty(n_rays)
    for f in range(n_fans):
        inv[:] = 0.0
        for k in range(n_k):
            qx = rel[f, k, 0]
            qy = rel[f, k, 1]
            q = qx * qx + qy * qy
            q -= r2[f, k]
            for j in range(n_rays):
                bj = b[k, f, j]
                disc = bj * bj - q
                t = 1.0 / (bj - math.sqrt(disc))
                if t > inv[j]:  # NaN (a miss) never is
                    inv[j] = t
        for j in range(n_rays):
            d = 1.0 / inv[j]
            if box.size:
                for axis in range(2):
                    c = dirs[axis, f, j]
                    wall = abs(((box[axis] if c > 0 else 0.0) - pose[f, axis]) / c)
                    if wall < d or wall != wall:  # np.minimum: NaN wins, then the smaller
                        d = wall
            out[f, j] = d
