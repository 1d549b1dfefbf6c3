"""Planar geometry shared by all estimators: angle wrapping and relative poses.

Poses are ``(x, y, heading)`` with heading in radians. Every function accepts
arrays with a trailing pose axis so it works on one pose or on a batch.
"""

from __future__ import annotations

import numpy as np

#: The largest float below pi: the top of the wrapped range.
PI_BELOW = float(np.nextafter(np.pi, 0.0))


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to ``[-pi, pi)``.

    An angle just below ``-pi`` (or just below an odd multiple of ``pi``) is
    congruent to an angle just below ``pi``; the shifted remainder can round up
    to ``2 pi`` there, so the result is capped at the largest float below ``pi``.
    """
    wrapped = (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi
    return np.minimum(wrapped, PI_BELOW)


def wrap_angle_in_place(angle: np.ndarray) -> None:
    """:func:`wrap_angle` written into the float array ``angle`` (the same operations)."""
    angle += np.pi
    angle %= 2.0 * np.pi
    angle -= np.pi
    np.minimum(angle, PI_BELOW, out=angle)


def relative_pose(pose_a: np.ndarray, pose_b: np.ndarray) -> np.ndarray:
    """Range, bearing and orientation of pose ``b`` seen from pose ``a``.

    ``r = |p_b - p_a|``, ``bearing = atan2(dy, dx) - phi_a``,
    ``orientation = phi_b - phi_a`` (angles wrapped). Shapes ``(..., 3)``.
    """
    pose_a = np.asarray(pose_a, dtype=float)
    pose_b = np.asarray(pose_b, dtype=float)
    d = pose_b[..., :2] - pose_a[..., :2]
    range_ = np.hypot(d[..., 0], d[..., 1])
    bearing = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - pose_a[..., 2])
    orientation = wrap_angle(pose_b[..., 2] - pose_a[..., 2])
    return np.stack([range_, bearing, orientation], axis=-1)


def compose_relative(pose_a: np.ndarray, rbo: np.ndarray) -> np.ndarray:
    """Inverse of :func:`relative_pose`: the pose at ``(range, bearing, orientation)`` from a."""
    pose_a = np.asarray(pose_a, dtype=float)
    rbo = np.asarray(rbo, dtype=float)
    ang = pose_a[..., 2] + rbo[..., 1]
    x = pose_a[..., 0] + rbo[..., 0] * np.cos(ang)
    y = pose_a[..., 1] + rbo[..., 0] * np.sin(ang)
    heading = wrap_angle(pose_a[..., 2] + rbo[..., 2])
    return np.stack([x, y, heading], axis=-1)
