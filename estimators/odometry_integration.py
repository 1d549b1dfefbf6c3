"""Odometry ``(v, w, dt)`` integrated into a relative pose with its covariance.

What :class:`estimators.mle_online.TeamMLE` turns into the offsets of its keyframes and
the measurements of its motion factors (Euler integration, the process model of
Madhavan et al.'s Eq. 1, with first-order covariance propagation as in an EKF
prediction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def pose_jacobians(pose: np.ndarray, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of ``compose(pose, delta)`` w.r.t. ``pose`` and ``delta`` (3x3 each)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    j_pose = np.eye(3)
    j_pose[0, 2] = -s * delta[0] - c * delta[1]
    j_pose[1, 2] = c * delta[0] - s * delta[1]
    j_delta = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return j_pose, j_delta


@dataclass
class OdometryIntegrator:
    """Relative motion since a reference pose, integrated from ``(v, w, dt)`` with covariance.

    ``delta`` is the pose relative to the start (in the start's frame) and ``cov``
    its covariance, propagated with ``P <- F P F^T + G Q G^T`` (Q = diag of the
    speed and turn-rate variances), as in an EKF prediction.
    """

    delta: np.ndarray
    cov: np.ndarray
    duration: float = 0.0

    @classmethod
    def zero(cls) -> OdometryIntegrator:
        """An integrator at the start (no motion, zero covariance)."""
        return cls(np.zeros(3), np.zeros((3, 3)), 0.0)

    def add(self, v: float, w: float, dt: float, std_v: float, std_w: float) -> None:
        """Integrate one odometry reading (forward speed ``v``, turn rate ``w``) over ``dt``."""
        th = self.delta[2]
        c, s = np.cos(th), np.sin(th)
        f = np.array([[1.0, 0.0, -dt * v * s], [0.0, 1.0, dt * v * c], [0.0, 0.0, 1.0]])
        g = dt * np.array([[c, 0.0], [s, 0.0], [0.0, 1.0]])
        q = np.diag([std_v**2, std_w**2])
        self.cov = f @ self.cov @ f.T + g @ q @ g.T
        self.delta = self.delta + dt * np.array([v * c, v * s, w])
        self.duration += dt


def integrate_odometry(
    v: np.ndarray, w: np.ndarray, dt: np.ndarray, std_v: float, std_w: float
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate a sequence of odometry readings; returns ``(delta (3,), cov (3, 3))``."""
    v, w, dt = np.broadcast_arrays(*(np.asarray(a, dtype=float).ravel() for a in (v, w, dt)))
    acc = OdometryIntegrator.zero()
    for vi, wi, di in zip(v, w, dt, strict=True):
        acc.add(vi, wi, di, std_v, std_w)
    return acc.delta.copy(), acc.cov.copy()
