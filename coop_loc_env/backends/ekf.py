"""The EKF backend (Madhavan et al.): ``estimator="ekf"``, one :class:`PoseEKF` for its
robots, predicted with the odometry sub-steps and updated with DGPS, compass and the
cooperative relative-pose detections (chi-square gated)."""

from __future__ import annotations

import numpy as np

from coop_loc_env._step_kernels import odometry_variance_into
from coop_loc_env.backends.base import (
    EstimatorBackend,
    contact_variance,
    gaussian_features,
    noisy_start,
    stacked_team_odometry,
)
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.records import Readings
from coop_loc_env.world import World
from estimators.ekf import PoseEKF

_EYE2 = np.eye(2)
_EYE2.flags.writeable = False


def _odometry_variance(
    odo: np.ndarray, slip_std: float, encoder_var: np.ndarray, scale: float
) -> np.ndarray:
    """``scale * (encoder_var + (slip_std * odo)^2)`` of odometry ``(substeps, k, 2)`` with the
    ``(V, w)`` axis first: a fresh C-ordered ``(2, substeps, k)``; ``encoder_var`` ``(2, 1, 1)``."""
    var = np.empty((2, *odo.shape[:2]))
    odometry_variance_into(odo, float(slip_std), encoder_var.reshape(2), float(scale), var)
    return var


class EKFBackend(EstimatorBackend):
    """Per-robot EKFs (Madhavan et al.) for the robots in ``robots``.

    Each step: predict at the odometry rate, gated DGPS and compass updates,
    then the cooperative joint update (Eq. 3) for every detection between two
    EKF robots (``cooperative_updates``). Cross-backend detections are left to
    the backend of the observed robot. While a robot's bumper is pressed its
    odometry's translation is not trusted (:func:`contact_variance`); DGPS and
    compass lock-outs are recovered from and relative detections confirmed as
    described in :class:`~estimators.ekf.PoseEKF`.
    """

    feature_size = 10

    def __init__(self, cfg: ScenarioConfig, robots: np.ndarray, world: World | None = None) -> None:
        self.cfg = cfg
        self.robots = np.asarray(robots, dtype=int)
        # Global robot index -> position in ``robots`` (-1: another backend's robot).
        self._local_index = np.full(cfg.n_robots, -1)
        self._local_index[self.robots] = np.arange(len(self.robots))
        self._whole_team = bool(np.array_equal(self.robots, np.arange(cfg.n_robots)))
        self._encoder_var = np.array([cfg.odom_v_std**2, cfg.odom_w_std**2])[:, None, None]  # V, w
        self._encoder_var.flags.writeable = False
        self.ekf: PoseEKF | None = None
        self._contact_steps = np.zeros(len(self.robots), dtype=int)
        self._contact_run = False  # whether _contact_steps may hold a nonzero count

    def reset(self, true_poses: np.ndarray, rng: np.random.Generator) -> None:
        """Start each filter at a noisy draw around the true pose."""
        mean, std = noisy_start(self.cfg, true_poses, self.robots, rng)
        self.ekf = PoseEKF(mean, np.diag(std**2), gate_prob=self.cfg.gate_prob)
        self._contact_steps[:] = 0
        self._contact_run = False

    def step(self, readings: Readings, active: np.ndarray) -> dict[str, int]:
        """Fuse one step of readings; returns counts of accepted/rejected updates."""
        cfg = self.cfg
        ekf = self.ekf
        g = self.robots
        odo, dt_sub = stacked_team_odometry(cfg, readings, g, active, self._whole_team)
        pressed = readings.bumper
        if pressed is not None and np.count_nonzero(pressed):
            pressed = pressed if self._whole_team else pressed[g]
            self._contact_steps = np.where(pressed, self._contact_steps + 1, 0)
            self._contact_run = True
            hit = np.nonzero(pressed)[0]
            distance = np.abs(odo[:, hit, 0]).sum(axis=0) * dt_sub
            odo = odo.copy()
            odo[:, hit, 0] = 0.0  # the wheels' distance is no measure of motion now
        else:
            hit = None
            if self._contact_run:  # (nothing to clear on most steps)
                self._contact_steps[:] = 0
                self._contact_run = False
        # Encoder noise plus the wheel slip the robot's maker specifies, inflated by
        # ``ekf_process_noise_scale`` to cover what the model leaves out; (V, w) together.
        var = _odometry_variance(odo, cfg.slip_std, self._encoder_var, cfg.ekf_process_noise_scale)
        ekf.predict_sequence_stacked(odo[..., 0], odo[..., 1], dt_sub, var)
        if hit is not None:
            q = np.zeros((len(hit), 3, 3))
            q[:, 0, 0] = q[:, 1, 1] = contact_variance(distance, self._contact_steps[hit])
            ekf.inflate(hit, q)
        stats = {"accepted": 0, "rejected": 0, "cooperative": 0}
        whole = self._whole_team
        gps = readings.gps_mask
        sel = np.nonzero(gps if whole else gps[g])[0] if np.count_nonzero(gps) else ()
        if len(sel):
            fixed = sel if whole else g[sel]
            # Per-axis variance on the diagonal of each 2x2 noise matrix (finite: fixes only).
            r = readings.gps_var[fixed][:, None, None] * _EYE2
            ok = ekf.update_position(sel, readings.gps_xy[fixed], r)
            n_ok = np.count_nonzero(ok)
            stats["accepted"] += n_ok
            stats["rejected"] += len(ok) - n_ok
        compass = readings.compass_mask
        sel = np.nonzero(compass if whole else compass[g])[0] if np.count_nonzero(compass) else ()
        if len(sel):
            ok = ekf.update_heading(
                sel,
                readings.compass[sel if whole else g[sel]],
                np.full(len(sel), cfg.compass_std**2),
            )
            n_ok = np.count_nonzero(ok)
            stats["accepted"] += n_ok
            stats["rejected"] += len(ok) - n_ok
        det = readings.detections
        if cfg.cooperative_updates and len(det):
            if whole:  # every detection is between two of this backend's robots
                rows, ia, ib = slice(None), det.observer, det.target
            else:
                ia, ib = self._local_index[det.observer], self._local_index[det.target]
                rows = np.nonzero((ia >= 0) & (ib >= 0))[0]
                ia, ib = ia[rows], ib[rows]
            if len(ia):
                ok = ekf.update_relative(
                    ia,
                    ib,
                    det.z[rows],
                    det.cov[rows],
                    fusion=cfg.cooperative_fusion,
                    max_rounds=cfg.cooperative_rounds_per_step,
                )
                n_ok = np.count_nonzero(ok)
                stats["cooperative"] += n_ok
                stats["rejected"] += len(ok) - n_ok
        return stats

    def mean(self) -> np.ndarray:
        """Estimated poses ``(k, 3)``."""
        return self.ekf.mean

    def cov(self) -> np.ndarray:
        """Pose covariances ``(k, 3, 3)``."""
        return self.ekf.cov

    def features(self) -> np.ndarray:
        """Belief features of this backend's robots ``(k, 10)`` (:func:`gaussian_features`)."""
        return gaussian_features(self.ekf.mean, self.ekf.cov, self.cfg.world_size)
