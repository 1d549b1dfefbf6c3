"""SE(2) helpers and the factor residuals of the pose graph, with analytic Jacobians.

* Motion residual (:func:`between_residual`): the SE(2) logarithm
  ``Log(T_mu^-1 T_i^-1 T_j)``, the same function as GTSAM's ``BetweenFactorPose2``.
  It is smooth everywhere, in particular when the robot did not move.
* Robot-observation residual (:func:`observation_residual`): range, bearing and
  orientation of one pose seen from another (Howard et al., Eq. 15 form), optionally
  with known pose offsets; angles wrapped, derivatives finite at ``r = 0``.

All functions are vectorized over a leading axis of factors.
"""

from __future__ import annotations

import numpy as np

from estimators.geometry import wrap_angle

DEFAULT_MIN_RANGE = 1e-6
"""Floor on the range used in observation derivatives (metres)."""


def check_pose(pose: np.ndarray, name: str) -> np.ndarray:
    pose = np.array(pose, dtype=float)  # a copy: callers' arrays are never modified
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name} must be 3 finite numbers (x, y, heading), got {pose!r}")
    return pose


def sqrt_information(cov: np.ndarray, name: str = "cov") -> np.ndarray:
    """Lower-triangular ``W`` with ``W^T W = cov^-1``; raises ``ValueError`` if not SPD."""
    cov = np.asarray(cov, dtype=float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or not np.all(np.isfinite(cov)):
        raise ValueError(f"{name} must be a finite square matrix, got {cov!r}")
    if np.abs(cov - cov.T).max(initial=0.0) > 1e-9 * np.abs(cov).max(initial=0.0) + 1e-15:
        raise ValueError(f"{name} must be symmetric, got {cov!r}")
    try:
        lower = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be positive definite, got {cov!r}") from None
    # cov = L L^T  =>  cov^-1 = L^-T L^-1 = W^T W with W = L^-1.
    return np.linalg.solve(lower, np.eye(len(cov)))


def se2_log_coefficients(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a(psi) = (psi/2) cot(psi/2)`` and its derivative (series near 0)."""
    psi = np.asarray(psi, dtype=float)
    small = np.abs(psi) < 1e-4
    half = np.where(small, 1.0, psi / 2.0)
    tan_half = np.tan(half)
    a = np.where(small, 1.0 - psi**2 / 12.0, half / np.where(small, 1.0, tan_half))
    # d/dpsi [h cot h] with h = psi/2: 0.5 * (cot h - h / sin^2 h)
    sin_half = np.sin(half)
    da = np.where(
        small, -psi / 6.0, 0.5 * (1.0 / np.where(small, 1.0, tan_half) - half / sin_half**2)
    )
    return a, da


def between_residual(
    xi: np.ndarray, xj: np.ndarray, mu: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SE(2) log residual ``Log(T_mu^-1 T_i^-1 T_j)`` and its Jacobians w.r.t. ``xi`` and ``xj``.

    Shapes: ``xi, xj, mu`` are ``(m, 3)``; returns ``e (m, 3)``, ``Ji, Jj (m, 3, 3)``.
    """
    c, s = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
    ux, uy = c * dx + s * dy, -s * dx + c * dy
    cm, sm = np.cos(mu[:, 2]), np.sin(mu[:, 2])
    px, py = ux - mu[:, 0], uy - mu[:, 1]
    wx, wy = cm * px + sm * py, -sm * px + cm * py
    psi = wrap_angle(xj[:, 2] - xi[:, 2] - mu[:, 2])
    a, da = se2_log_coefficients(psi)
    b = 0.5 * psi
    e = np.stack([a * wx + b * wy, -b * wx + a * wy, psi], axis=-1)

    m = len(xi)
    # d e_xy / d w = M = [[a, b], [-b, a]];  d w / d u = Rm^T;  d e_xy / d psi = M' w
    mr = np.empty((m, 2, 2))  # M @ Rm^T
    mr[:, 0, 0] = a * cm - b * sm
    mr[:, 0, 1] = a * sm + b * cm
    mr[:, 1, 0] = -b * cm - a * sm
    mr[:, 1, 1] = -b * sm + a * cm
    dpsi = np.stack([da * wx + 0.5 * wy, -0.5 * wx + da * wy], axis=-1)  # (m, 2)
    # d u / d xi = [[-c, -s, uy], [s, -c, -ux]];  d u / d xj = [[c, s, 0], [-s, c, 0]]
    du_dpj = np.empty((m, 2, 2))
    du_dpj[:, 0, 0], du_dpj[:, 0, 1] = c, s
    du_dpj[:, 1, 0], du_dpj[:, 1, 1] = -s, c
    mrr = mr @ du_dpj  # d e_xy / d p_j
    ji = np.zeros((m, 3, 3))
    jj = np.zeros((m, 3, 3))
    jj[:, :2, :2] = mrr
    jj[:, :2, 2] = dpsi
    jj[:, 2, 2] = 1.0
    ji[:, :2, :2] = -mrr
    ji[:, :2, 2] = mr[:, :, 0] * uy[:, None] - mr[:, :, 1] * ux[:, None] - dpsi
    ji[:, 2, 2] = -1.0
    return e, ji, jj


def _offset_pose(x: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x (+) off`` (offset in the frame of ``x``) and its Jacobian w.r.t. ``x``."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    ox, oy = off[:, 0], off[:, 1]
    out = np.stack([x[:, 0] + c * ox - s * oy, x[:, 1] + s * ox + c * oy, x[:, 2] + off[:, 2]], -1)
    jac = np.zeros((len(x), 3, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = jac[:, 2, 2] = 1.0
    jac[:, 0, 2] = -s * ox - c * oy
    jac[:, 1, 2] = c * ox - s * oy
    return out, jac


def observation_residual(
    xa: np.ndarray,
    xb: np.ndarray,
    mu: np.ndarray,
    off_a: np.ndarray | None = None,
    off_b: np.ndarray | None = None,
    min_range: float = DEFAULT_MIN_RANGE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual ``G(xa (+) off_a, xb (+) off_b) - mu`` (range, bearing, orientation) and Jacobians.

    Angles are wrapped. Derivatives use ``max(r, min_range)``, so they stay finite at
    ``r = 0``; closer than ``min_range`` they are taken along the measured bearing.
    Shapes as in :func:`between_residual`.
    """
    m = len(xa)
    if off_a is None:
        off_a = np.zeros((m, 3))
    if off_b is None:
        off_b = np.zeros((m, 3))
    pa, ta = _offset_pose(xa, off_a)
    pb, tb = _offset_pose(xb, off_b)
    dx, dy = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    r = np.hypot(dx, dy)
    rr = np.maximum(r, min_range)
    e = np.stack(
        [
            r - mu[:, 0],
            wrap_angle(np.arctan2(dy, dx) - pa[:, 2] - mu[:, 1]),
            wrap_angle(pb[:, 2] - pa[:, 2] - mu[:, 2]),
        ],
        axis=-1,
    )
    # Below min_range the direction is undefined: differentiate as if b sat
    # min_range away along the measured bearing (a subgradient of the range cone),
    # so coincident robots still constrain each other instead of giving zero rows.
    close = r < min_range
    if np.any(close):
        phi = pa[close, 2] + mu[close, 1]
        dx, dy = dx.copy(), dy.copy()
        dx[close], dy[close] = min_range * np.cos(phi), min_range * np.sin(phi)
    ga = np.zeros((m, 3, 3))
    ga[:, 0, 0], ga[:, 0, 1] = -dx / rr, -dy / rr
    ga[:, 1, 0], ga[:, 1, 1], ga[:, 1, 2] = dy / rr**2, -dx / rr**2, -1.0
    ga[:, 2, 2] = -1.0
    gb = np.zeros((m, 3, 3))
    gb[:, 0, 0], gb[:, 0, 1] = dx / rr, dy / rr
    gb[:, 1, 0], gb[:, 1, 1] = -dy / rr**2, dx / rr**2
    gb[:, 2, 2] = 1.0
    return e, ga @ ta, gb @ tb


def se2_exp(xi: np.ndarray) -> np.ndarray:
    """SE(2) exponential of tangent vectors ``(..., 3)`` as poses ``(x, y, heading)``."""
    xi = np.asarray(xi, dtype=float)
    th = xi[..., 2]
    small = np.abs(th) < 1e-6
    ths = np.where(small, 1.0, th)
    sa = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    cb = np.where(small, th / 2.0, (1.0 - np.cos(ths)) / ths)
    x = sa * xi[..., 0] - cb * xi[..., 1]
    y = cb * xi[..., 0] + sa * xi[..., 1]
    return np.stack([x, y, wrap_angle(th)], axis=-1)


def compose(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``pose (+) delta``: the pose at ``delta`` expressed in the frame of ``pose``."""
    pose, delta = np.asarray(pose, dtype=float), np.asarray(delta, dtype=float)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack(
        [
            pose[..., 0] + c * delta[..., 0] - s * delta[..., 1],
            pose[..., 1] + s * delta[..., 0] + c * delta[..., 1],
            wrap_angle(pose[..., 2] + delta[..., 2]),
        ],
        axis=-1,
    )


def between(pose_a: np.ndarray, pose_b: np.ndarray) -> np.ndarray:
    """``pose_a^-1 (+) pose_b``: pose ``b`` in the frame of pose ``a``."""
    pose_a, pose_b = np.asarray(pose_a, dtype=float), np.asarray(pose_b, dtype=float)
    c, s = np.cos(pose_a[..., 2]), np.sin(pose_a[..., 2])
    dx, dy = pose_b[..., 0] - pose_a[..., 0], pose_b[..., 1] - pose_a[..., 1]
    return np.stack(
        [c * dx + s * dy, -s * dx + c * dy, wrap_angle(pose_b[..., 2] - pose_a[..., 2])], axis=-1
    )
