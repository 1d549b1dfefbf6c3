"""Compiled loop (numba, cached on disk) of the EKF's multi-step prediction.

One pass does what a chain of small numpy operations would, with the same IEEE
operations in the same order (no fast-math, no fused multiply-adds), so the
result is bit-identical to the numpy formulation of :func:`estimators.ekf._propagate`
that it serves; the trigonometry stays in numpy.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from estimators.geometry import PI_BELOW

__all__ = ["propagate_rest"]

_PI = np.pi
_TWO_PI = 2.0 * np.pi


@njit(cache=True)
def propagate_rest(
    mean: np.ndarray, p: np.ndarray, v: np.ndarray, dt: float, q: np.ndarray,
    phi_last: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """The part of :func:`estimators.ekf._propagate` after the headings, in place.

    ``mean`` ``(k, 3)`` and ``p`` ``(k, 3, 3)`` are updated; ``v`` ``(T, k)``;
    ``q`` ``(2, T, k)`` the variances of ``v`` and ``w`` (unscaled, left as is);
    ``phi_last`` ``(k,)`` the heading after the last substep (unwrapped);
    ``cos_h``, ``sin_h`` ``(T, k)`` of the heading before each substep.
    """
    n_sub, k = v.shape
    mdt = -dt
    dt2 = dt * dt
    bcum = np.empty(n_sub)
    acum = np.empty(n_sub)
    for r in range(k):
        # Jacobian entries b_t = dt v cos, a_t = -dt v sin and their running sums.
        sb = 0.0
        sa = 0.0
        for t in range(n_sub):
            vt = v[t, r]
            bt = cos_h[t, r] * (vt * dt)
            at = sin_h[t, r] * (vt * mdt)
            sb = bt if t == 0 else sb + bt
            sa = at if t == 0 else sa + at
            bcum[t] = sb
            acum[t] = sa
        big_b = bcum[n_sub - 1]
        big_a = acum[n_sub - 1]
        mean[r, 0] += big_b * 1.0
        mean[r, 1] += big_a * -1.0
        h = phi_last[r] + _PI
        h %= _TWO_PI
        h -= _PI
        mean[r, 2] = h if h < PI_BELOW or h != h else PI_BELOW
        # F P F^T with F = I + A e02 + B e12: rows 0 and 1 first, then columns 0 and 1.
        for c in range(3):
            p2c = p[r, 2, c]
            p[r, 0, c] += big_a * p2c
            p[r, 1, c] += big_b * p2c
        for i in range(3):
            pi2 = p[r, i, 2]
            p[r, i, 0] += pi2 * big_a
            p[r, i, 1] += pi2 * big_b
        # Noise: sum over the 2 T columns l0 = (c, s, 0) (weight dt^2 var_v) and
        # l1 = (a', b', 1) (weight dt^2 var_w), a'_t = A - a_cum_t, b'_t = B - b_cum_t.
        s00 = 0.0
        s01 = 0.0
        s02 = 0.0
        s11 = 0.0
        s12 = 0.0
        s22 = 0.0
        for m in range(2):
            for t in range(n_sub):
                w = q[m, t, r] * dt2
                if m == 0:
                    l0 = cos_h[t, r]
                    l1 = sin_h[t, r]
                    l2 = 0.0
                else:
                    l0 = big_a - acum[t]
                    l1 = big_b - bcum[t]
                    l2 = 1.0
                s00 += l0 * l0 * w
                s01 += l0 * l1 * w
                s02 += l0 * l2 * w
                s11 += l1 * l1 * w
                s12 += l1 * l2 * w
                s22 += l2 * l2 * w
        p[r, 0, 0] += s00
        p[r, 0, 1] += s01
        p[r, 0, 2] += s02
        p[r, 1, 0] += s01
        p[r, 1, 1] += s11
        p[r, 1, 2] += s12
        p[r, 2, 0] += s02
        p[r, 2, 1] += s12
        p[r, 2, 2] += s22
