"""Relative-pose error metrics of Howard, Mataric and Sukhatme (their Eq. 15).

The global frame of a team estimate is arbitrary, so accuracy is measured on
relative poses: for every ordered pair of robots ``(a, b)``, the range, bearing
and orientation of ``b`` seen from ``a`` in the estimate are compared with the
truth. The paper's metric is the mean absolute error over pairs, e.g.
``e_r = mean_{a != b} |r_ab(est) - r_ab(true)|``; bearing and orientation
errors are wrapped to ``[-pi, pi)`` before taking the absolute value.

Everything works on arrays ``(..., N, 3)`` (leading axes, e.g. time, are kept),
so the functions run on simulated episodes and on real logs alike.
"""

from __future__ import annotations

import numpy as np

from estimators.geometry import relative_pose, wrap_angle

ERROR_NAMES = ("relative_range_error", "relative_bearing_error", "relative_orientation_error")
"""Keys under which the three errors are reported (e.g. in an environment's ``info``)."""


def relative_pose_matrix(poses: np.ndarray) -> np.ndarray:
    """All pairwise relative poses, ``out[..., a, b] = relative_pose(pose_a, pose_b)``.

    ``poses`` is ``(..., N, 3)``; the result is ``(..., N, N, 3)`` (range, bearing,
    orientation of ``b`` seen from ``a``; the diagonal is zero).
    """
    poses = np.asarray(poses, dtype=float)
    rel = relative_pose(poses[..., :, None, :], poses[..., None, :, :])
    n = poses.shape[-2]
    rel[..., np.arange(n), np.arange(n), :] = 0.0  # bearing to oneself is undefined: 0
    return rel


def _check(estimated: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    est = np.asarray(estimated, dtype=float)
    tru = np.asarray(true, dtype=float)
    if est.ndim < 2 or est.shape[-1] != 3 or est.shape[-2] < 2:
        raise ValueError(f"estimated poses must have shape (..., N>=2, 3), got {est.shape}")
    if tru.shape != est.shape:
        raise ValueError(f"true poses shape {tru.shape} differs from estimated {est.shape}")
    if not (np.all(np.isfinite(est)) and np.all(np.isfinite(tru))):
        raise ValueError("poses must be finite")
    return est, tru


def pairwise_errors(estimated: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Absolute range/bearing/orientation errors of every ordered pair, ``(..., N, N, 3)``.

    The diagonal (a robot relative to itself) is zero.
    """
    est, tru = _check(estimated, true)
    diff = relative_pose_matrix(est) - relative_pose_matrix(tru)
    diff[..., 1:] = wrap_angle(diff[..., 1:])
    return np.abs(diff)


def relative_matrix_errors(
    estimated_rel: np.ndarray, true_rel: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Eq. 15 errors from relative-pose matrices ``(..., N, N, 3)`` directly.

    For estimators that report relative poses rather than poses in a common frame
    (e.g. ``TeamMLE.relative_poses()``). Returns ``(..., 3)`` as :func:`relative_errors`.
    """
    est = np.asarray(estimated_rel, dtype=float)
    tru = np.asarray(true_rel, dtype=float)
    if est.ndim < 3 or est.shape[-1] != 3 or est.shape[-2] != est.shape[-3] or est.shape[-2] < 2:
        raise ValueError(f"relative poses must have shape (..., N>=2, N, 3), got {est.shape}")
    if tru.shape != est.shape:
        raise ValueError(f"true relative poses shape {tru.shape} differs from {est.shape}")
    if not (np.all(np.isfinite(est)) and np.all(np.isfinite(tru))):
        raise ValueError("relative poses must be finite")
    err = np.abs(est - tru)
    err[..., 1:] = np.abs(wrap_angle(est[..., 1:] - tru[..., 1:]))
    n = err.shape[-2]
    pairs = _pair_mask(n, mask, err.shape[:-3])
    count = pairs.sum(axis=(-1, -2))
    if np.any(count == 0):
        raise ValueError("relative errors need at least two robots (after masking)")
    return (err * pairs[..., None]).sum(axis=(-3, -2)) / count[..., None]


def _pair_mask(n: int, mask: np.ndarray | None, lead: tuple[int, ...]) -> np.ndarray:
    off_diag = ~np.eye(n, dtype=bool)
    if mask is None:
        return np.broadcast_to(off_diag, (*lead, n, n))
    m = np.asarray(mask, dtype=bool)
    if m.shape[-1] != n:
        raise ValueError(f"mask must have N = {n} robots on its last axis, got {m.shape}")
    m = np.broadcast_to(m, (*lead, n))
    return m[..., :, None] & m[..., None, :] & off_diag


def relative_errors(
    estimated: np.ndarray, true: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Eq. 15: mean absolute range, bearing and orientation error over ordered pairs.

    ``estimated`` and ``true`` are ``(..., N, 3)``; ``mask`` (``(..., N)`` bool,
    optional) restricts the pairs to robots flagged true. Returns ``(..., 3)``:
    ``[e_range, e_bearing, e_orientation]``. Raises ``ValueError`` if fewer than
    two robots remain.
    """
    err = pairwise_errors(estimated, true)
    n = err.shape[-2]
    pairs = _pair_mask(n, mask, err.shape[:-3])
    count = pairs.sum(axis=(-1, -2))
    if np.any(count == 0):
        raise ValueError("relative errors need at least two robots (after masking)")
    return (err * pairs[..., None]).sum(axis=(-3, -2)) / count[..., None]


def relative_errors_per_robot(
    estimated: np.ndarray, true: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """Mean errors of each robot's view of its teammates, ``(..., N, 3)``.

    Row ``a`` averages the errors of ``(a, b)`` over ``b != a`` (and ``mask``).
    Robots excluded by ``mask`` (or with no teammate) get ``nan``-free zeros.
    """
    err = pairwise_errors(estimated, true)
    n = err.shape[-2]
    pairs = _pair_mask(n, mask, err.shape[:-3])
    count = pairs.sum(axis=-1)
    total = (err * pairs[..., None]).sum(axis=-2)
    return total / np.maximum(count, 1)[..., None]


def relative_error_dict(estimated: np.ndarray, true: np.ndarray) -> dict[str, float]:
    """Team-mean Eq. 15 errors of one snapshot ``(N, 3)`` keyed by :data:`ERROR_NAMES`."""
    values = relative_errors(estimated, true)
    if values.ndim != 1:
        raise ValueError(f"expected one snapshot of shape (N, 3), got {np.shape(estimated)}")
    return {name: float(v) for name, v in zip(ERROR_NAMES, values, strict=True)}
