"""The odometry motion model's arithmetic (Thrun et al.'s rot1 / trans / rot2 decomposition).

:func:`compose_odometry` turns a sequence of unicycle odometry readings into one relative
motion; :func:`motion_parameters` decomposes a relative motion and gives the noise
standard deviations of :class:`~estimators.mcl.config.ParticleMotionNoise`, the
parameters the compiled motion update (:func:`estimators.mcl._team_kernels.predict_blocks`)
reads.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.geometry import PI_BELOW
from estimators.mcl.config import ParticleMotionNoise

__all__ = ["compose_odometry", "motion_parameters"]


def compose_odometry(v: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Relative motion ``(dx, dy, dheading)`` of a sequence of unicycle odometry readings.

    ``v``, ``w`` ``(K,)`` are speeds and turn rates held for ``dt`` each; the
    result is expressed in the robot frame at the start (exact arcs), ready for
    :meth:`ParticleFilter.predict_delta`. One prediction per env step instead
    of one per odometry sub-step keeps the sampling cost down.
    """
    v = np.atleast_1d(np.asarray(v, dtype=float))
    w = np.atleast_1d(np.asarray(w, dtype=float))
    if v.shape != w.shape or v.ndim != 1:
        raise ValueError(f"v and w must be 1D of equal length, got {v.shape} and {w.shape}")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(w)) and math.isfinite(dt)) or dt < 0:
        raise ValueError(f"odometry must be finite with dt >= 0, got v={v}, w={w}, dt={dt}")
    dth = w * dt
    start = np.concatenate([[0.0], np.cumsum(dth)[:-1]])
    turning = np.abs(dth) > 1e-9
    safe_w = np.where(turning, w, 1.0)
    lx = np.where(turning, v / safe_w * np.sin(dth), v * dt)
    ly = np.where(turning, v / safe_w * (1.0 - np.cos(dth)), 0.0)
    c, s = np.cos(start), np.sin(start)
    return np.array([np.sum(c * lx - s * ly), np.sum(s * lx + c * ly), float(np.sum(dth))])


def motion_parameters(dx: float, dy: float, dth: float,
                      noise: ParticleMotionNoise) -> tuple[float, ...]:
    """``rot1, trans, rot2`` of the relative motion ``(dx, dy, dth)`` (reversing gives a
    negative translation, not a half-turn) and their noise standard deviations
    ``sd_rot1, sd_trans, sd_rot2``."""
    trans = math.hypot(dx, dy)
    if trans < 1e-9:
        rot1 = 0.0
    elif dx >= 0:
        rot1 = math.atan2(dy, dx)
    else:  # reversing: negative translation, not a half-turn
        rot1 = math.atan2(-dy, -dx)
        trans = -trans
    rot2 = min((dth - rot1 + math.pi) % (2.0 * math.pi) - math.pi, PI_BELOW)
    at = abs(trans)
    mn = noise
    sd_r1 = mn.rot_rot * abs(rot1) + mn.rot_trans * at + mn.min_heading
    sd_t = mn.trans_trans * at + mn.trans_rot * (abs(rot1) + abs(rot2)) + mn.min_xy
    sd_r2 = mn.rot_rot * abs(rot2) + mn.rot_trans * at + mn.min_heading
    return rot1, trans, rot2, sd_r1, sd_t, sd_r2
