"""Relative-pose measurement models and covariance-intersection weights of the
cooperative EKF update (:meth:`estimators.ekf.PoseEKF.update_relative`)."""

from __future__ import annotations

import numpy as np

from estimators.geometry import wrap_angle_in_place


def relative_measurement(
    xa: np.ndarray, xb: np.ndarray, model: str = "rbo"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted relative measurement of ``xb`` from ``xa`` and its Jacobians.

    Returns ``(h, H_a, H_b)`` with shapes ``(k, 3)``, ``(k, 3, 3)``, ``(k, 3, 3)``.
    For ``model="rbo"`` the range is floored at 1 mm so the bearing Jacobian
    stays finite when two estimates coincide.
    """
    if model not in ("rbo", "cartesian"):
        raise ValueError(f"unknown relative measurement model {model!r}")
    xa = np.asarray(xa, dtype=float).reshape(-1, 3)
    xb = np.asarray(xb, dtype=float).reshape(-1, 3)
    if xa.shape != xb.shape:
        raise ValueError(f"xa and xb must have the same shape, got {xa.shape} and {xb.shape}")
    h, jac = stacked_relative_measurement(xa, xb, model)
    return h, jac[:, :, :3].copy(), jac[:, :, 3:].copy()


# Constant entries of the stacked Jacobians [H_a, H_b] (3, 6) of the two models.
_JAC_CONST = {
    "cartesian": np.hstack([np.eye(3), -np.eye(3)]),
    "rbo": np.array([[0.0] * 6, [0, 0, -1, 0, 0, 0], [0, 0, -1, 0, 0, 1]], dtype=float),
}
for _jac in _JAC_CONST.values():
    _jac.flags.writeable = False
_FLIP = np.array([1.0, -1.0])


def stacked_relative_measurement(
    xa: np.ndarray, xb: np.ndarray, model: str
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`relative_measurement` of ``(k, 3)`` float poses with the Jacobians side by
    side: ``(h (k, 3), [H_a, H_b] (k, 3, 6))``."""
    k = len(xa)
    jac = np.empty((k, 3, 6))
    jac[:] = _JAC_CONST[model]
    if model == "cartesian":
        h = xa - xb
        wrap_angle_in_place(h[:, 2])
        return h, jac
    d = xb[:, :2] - xa[:, :2]  # (dx, dy)
    sq = d * d
    q = sq[:, 0] + sq[:, 1]
    np.maximum(q, 1e-6, out=q)
    h = np.empty((k, 3))
    rng = np.sqrt(q, out=h[:, 0])
    np.arctan2(d[:, 1], d[:, 0], out=h[:, 1])
    h[:, 2] = xb[:, 2]
    h[:, 1:] -= xa[:, 2:3]
    wrap_angle_in_place(h[:, 1:])
    # Range row: (-dx, -dy, 0, dx, dy, 0) / range; bearing row: (dy, -dx, -1, -dy, dx, 0) / q.
    ur = d / rng[:, None]
    jac[:, 0, 3:5] = ur
    np.negative(ur, out=jac[:, 0, :2])
    bearing = jac[:, 1, :2]
    np.multiply(d[:, ::-1] / q[:, None], _FLIP, out=bearing)
    np.negative(bearing, out=jac[:, 1, 3:5])
    return h, jac


_CI_WEIGHTS = np.linspace(0.05, 0.95, 10)
_CI_WEIGHTS.flags.writeable = False
# The weights of robot a (w) and robot b (1 - w), shaped to divide (2, 1, k, m, m) blocks.
_CI_SCALES = np.stack([_CI_WEIGHTS, 1 - _CI_WEIGHTS])[:, :, None, None, None]
_CI_SCALES.flags.writeable = False


def best_ci_weight(pab: np.ndarray, jac: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Covariance-intersection weight per pair (grid search over ``_CI_WEIGHTS``).

    ``pab (2, k, 3, 3)``: the priors ``P_a``, ``P_b``; ``jac (k, m, 6)``: ``[H_a, H_b]``;
    ``r (k, m, m)``.

    Minimizes the summed trace of the two robots' covariances after the update,
    counting a robot whose inflated posterior would exceed its prior at its prior
    (the update leaves such a robot unchanged).

    With ``P_a / w``, ``P_b / (1 - w)`` on the diagonal, ``U_a = P_a H_a^T``,
    ``U_b = P_b H_b^T`` and ``S(w) = H_a U_a / w + H_b U_b / (1 - w) + R``, robot
    ``a``'s posterior trace is ``tr P_a / w - tr(S(w)^-1 U_a^T U_a) / w^2`` (and
    likewise for ``b`` with ``1 - w``): only ``m x m`` matrices per weight.
    """
    k, m = jac.shape[:2]
    jab = jac.reshape(k, m, 2, 3).transpose(2, 0, 1, 3)  # (2, k, m, 3): H_a, H_b
    u = pab @ jab.mT  # (2, k, 3, m)
    s = (jab @ u)[:, None] / _CI_SCALES  # (2, weights, k, m, m)
    s = s[0] + s[1]
    s += r
    gram = u.mT @ u  # (2, k, m, m), symmetric
    if m == 3 and k >= _COFACTOR_MIN_PAIRS:
        # tr(S^-1 G) = sum(C * G) / det S with C the cofactors of S (G symmetric): a
        # few whole-array operations instead of LAPACK's per-matrix cost.
        cof, det = _cofactors3(s)
        reduction = np.einsum("wkij,gkij->gwk", cof, gram) / det
    else:
        reduction = np.einsum("wkij,gkij->gwk", np.linalg.inv(s), gram)
    prior = pab.trace(axis1=2, axis2=3)[:, None]  # (2, 1, k)
    scale = _CI_SCALES[..., 0, 0]  # (2, weights, 1): w and 1 - w
    post = prior / scale - reduction / (scale * scale)
    np.minimum(post, prior, out=post)
    return _CI_WEIGHTS[np.argmin(post[0] + post[1], axis=0)]


# From this many pairs on, best_ci_weight's 10 k 3x3 systems go through cofactors
# (cheaper than np.linalg.inv from about 40 matrices on).
_COFACTOR_MIN_PAIRS = 4
_NEXT = np.array([1, 2, 0])
_AFTER_NEXT = np.array([2, 0, 1])


def _cofactors3(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cofactor matrices and determinants of a stack of 3x3 matrices ``s (..., 3, 3)``.

    Row ``i`` of the cofactors is ``row_{i+1} x row_{i+2}`` (indices mod 3), so
    ``S^-1 = C^T / det S`` with ``det S = row_0 . C_0``.
    """
    a, b = s[..., _NEXT, :], s[..., _AFTER_NEXT, :]
    cof = a[..., _NEXT] * b[..., _AFTER_NEXT]
    cof -= a[..., _AFTER_NEXT] * b[..., _NEXT]
    det = np.einsum("...j,...j->...", s[..., 0, :], cof[..., 0, :])
    return cof, det


def disjoint_rounds(
    idx_a: np.ndarray, idx_b: np.ndarray, n: int, max_rounds: int | None = None
) -> list[np.ndarray]:
    """Split pairs into rounds in which every robot index appears at most once (greedy, in
    order); only the first ``max_rounds`` rounds are formed (``None``: all)."""
    a_list, b_list = idx_a.tolist(), idx_b.tolist()
    remaining = list(range(len(a_list)))
    rounds = []
    while remaining and (max_rounds is None or len(rounds) < max_rounds):
        used = [False] * n
        take = []
        rest = []
        for row in remaining:
            a, b = a_list[row], b_list[row]
            if used[a] or used[b]:
                rest.append(row)
            else:
                used[a] = used[b] = True
                take.append(row)
        rounds.append(np.asarray(take, dtype=int))
        remaining = rest
    return rounds
