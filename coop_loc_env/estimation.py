"""Glue between the sensors and the estimators: one backend per estimator type.

A backend owns the robots of the team that run its estimator, consumes a
step's :class:`~coop_loc_env.records.Readings`, and reports its robots' beliefs
as a :class:`~coop_loc_env.records.Beliefs` record (Gaussian ``mean`` and ``cov``,
a fixed-size feature vector per robot for the observation and, for particle
filters, the particle sets). Backends never see the true poses except at :meth:`reset`, where
the initial belief is drawn around them (``init_pos_std``,
``init_heading_std``), as on a robot that was told roughly where it starts.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from coop_loc_env._step_kernels import gaussian_rows, odometry_variance_into
from coop_loc_env.backends import (  # the registry, re-exported where backends are built
    BACKENDS,  # noqa: F401
    backend_class,
    register_backend,  # noqa: F401
)
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.records import Beliefs
from coop_loc_env.sensors import Readings
from coop_loc_env.world import World
from estimators.ekf import PoseEKF


class EstimatorBackend:
    """Base class of estimator backends: everything the env calls on one.

    A backend owns the robots in :attr:`robots` (global indices) and is built as
    ``cls(cfg, robots, world)``. Subclasses implement :meth:`reset`, :meth:`step`,
    :meth:`mean`, :meth:`cov` and :meth:`features` and set :attr:`feature_size`;
    :meth:`beliefs` (what the env reads after a step) is built from those three by
    default; :attr:`feature_names`, :meth:`particle_filter` and :meth:`extra_info`
    have no-op defaults. Make one available as ``ScenarioConfig.estimator`` /
    ``RobotSpec.estimator`` with :func:`~coop_loc_env.backends.register_backend`; the
    ``extras`` keys it reads are its class attribute ``options``
    (:class:`~coop_loc_env.extras.BackendOptions`).
    """

    robots: np.ndarray  # global indices of the robots this backend estimates
    feature_size: int
    #: Names of the :meth:`features` columns; empty: unnamed (the env then names
    #: ``feature_size == 10`` beliefs with :data:`GAUSSIAN_FEATURE_NAMES`).
    feature_names: tuple[str, ...] = ()

    def reset(self, true_poses: np.ndarray, rng: np.random.Generator) -> None:
        """Start the beliefs around ``true_poses`` (the only time the truth is read)."""
        raise NotImplementedError

    def step(self, readings: Readings, active: np.ndarray) -> dict[str, int]:
        """Fuse one step of readings; returns counts of accepted/rejected updates."""
        raise NotImplementedError

    def mean(self) -> np.ndarray:
        """Estimated poses ``(k, 3)``."""
        raise NotImplementedError

    def cov(self) -> np.ndarray:
        """Pose covariances ``(k, 3, 3)``."""
        raise NotImplementedError

    def features(self) -> np.ndarray:
        """Belief features of this backend's robots, ``(k, feature_size)``."""
        raise NotImplementedError

    def beliefs(self) -> Beliefs:
        """This backend's robots' beliefs after the last step (or reset), as values: copies
        that later steps leave unchanged."""
        return Beliefs(self.robots, np.array(self.mean(), dtype=float),
                       np.array(self.cov(), dtype=float), self.features())

    def particle_filter(self, i: int) -> Any:
        """The particle filter of local robot ``i`` (the ``i``-th of :attr:`robots`), or
        ``None`` when its belief is no particle set (the default)."""
        return None

    def extra_info(self, true_poses: np.ndarray) -> dict[int, dict]:
        """Extra info entries per global robot index (may use the truth: logging only);
        none by default."""
        return {}


# Per feature column: the bounds it is clipped to (log10 stds, correlations; the
# others are unbounded) and what is subtracted after the scaling (positions).
_FEATURE_LOW = np.array([-np.inf] * 4 + [-3.0] * 3 + [-1.0] * 3)
_FEATURE_HIGH = np.array([np.inf] * 4 + [2.0] * 3 + [1.0] * 3)
_FEATURE_SHIFT = np.array([1.0, 1.0] + [0.0] * 8)
_EYE2 = np.eye(2)
_EYE2.flags.writeable = False


@functools.lru_cache(maxsize=16)
def _feature_scale(w: float, h: float) -> np.ndarray:
    """Per feature column factor: ``2 / w``, ``2 / h`` for the positions, ``0.5`` turning
    ``log10 var`` into ``log10 std``, 1 elsewhere; read-only, made once per world size."""
    scale = np.array([2.0 / w, 2.0 / h, 1.0, 1.0, 0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
    scale.flags.writeable = False
    return scale


def gaussian_features(
    mean: np.ndarray, cov: np.ndarray, world_size: tuple[float, float]
) -> np.ndarray:
    """Network-friendly encoding of Gaussian pose beliefs, shape ``(k, 10)``.

    ``mean (k, 3)``, ``cov (k, 3, 3)``. Layout per row: ``[x/W*2-1, y/H*2-1,
    cos(phi), sin(phi), log10 std_x, log10 std_y, log10 std_phi, rho_xy,
    rho_xphi, rho_yphi]`` (log stds clipped to [-3, 2], correlations to [-1, 1]).
    """
    w, h = world_size
    k = len(mean)
    flat = cov.reshape(k, 9)
    out = np.empty((k, 10))
    heading = mean[:, 2]
    log_var = np.log10(np.maximum(flat[:, ::4], 1e-12))  # the variances
    # The rest (stds, correlations, scaling, clipping) in one compiled pass.
    gaussian_rows(mean, flat, np.cos(heading), np.sin(heading), log_var, _feature_scale(w, h),
                  _FEATURE_SHIFT, _FEATURE_LOW, _FEATURE_HIGH, out)
    return out


def noisy_start(
    cfg: ScenarioConfig, true_poses: np.ndarray, robots: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Initial belief of ``robots``: a draw around the true start and its std ``(3,)``.

    Every backend starts from this (``init_pos_std``, ``init_heading_std``), as a
    robot that was told roughly where it starts; the std is floored at 1e-3.
    """
    std = np.array([cfg.init_pos_std, cfg.init_pos_std, cfg.init_heading_std])
    start = true_poses[robots] + rng.standard_normal((len(robots), 3)) * std
    return start, np.maximum(std, 1e-3)


def team_odometry(
    cfg: ScenarioConfig,
    readings: Readings,
    robots: np.ndarray,
    active: np.ndarray,
    whole_team: bool | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The step's odometry of ``robots``: ``(v, w)`` each ``(substeps, k)``, zero for robots
    no longer active, and the substep length in seconds. ``whole_team`` says (when known)
    whether ``robots`` is ``0 .. n-1`` in order."""
    odo, dt_sub = _team_odometry(cfg, readings, robots, active, whole_team)
    return odo[..., 0], odo[..., 1], dt_sub


def _team_odometry(
    cfg: ScenarioConfig,
    readings: Readings,
    robots: np.ndarray,
    active: np.ndarray,
    whole_team: bool | None,
) -> tuple[np.ndarray, float]:
    """:func:`team_odometry` with ``(v, w)`` stacked on a last axis: ``(substeps, k, 2)``
    (the readings' own array when nothing is zeroed or selected)."""
    dt_sub = cfg.dt / cfg.odometry_substeps
    odo = readings.odometry
    if whole_team is None:
        whole_team = len(robots) == odo.shape[1] and bool((robots == _arange(len(robots))).all())
    if whole_team:
        if np.count_nonzero(active) == active.size:
            return odo, dt_sub
        return np.where(active[:, None], odo, 0.0), dt_sub
    return np.where(active[robots, None], odo[:, robots], 0.0), dt_sub


@functools.lru_cache(maxsize=16)
def _arange(n: int) -> np.ndarray:
    """``np.arange(n)``, made once per ``n`` and read-only (it is shared)."""
    out = np.arange(n)
    out.flags.writeable = False
    return out


def _odometry_variance(
    odo: np.ndarray, slip_std: float, encoder_var: np.ndarray, scale: float
) -> np.ndarray:
    """``scale * (encoder_var + (slip_std * odo)^2)`` of odometry ``(substeps, k, 2)`` with the
    ``(V, w)`` axis first: a fresh C-ordered ``(2, substeps, k)``; ``encoder_var`` ``(2, 1, 1)``."""
    var = np.empty((2, *odo.shape[:2]))
    odometry_variance_into(odo, float(slip_std), encoder_var.reshape(2), float(scale), var)
    return var


GAUSSIAN_FEATURE_NAMES = (
    "x_norm",
    "y_norm",
    "cos_heading",
    "sin_heading",
    "log10_std_x",
    "log10_std_y",
    "log10_std_heading",
    "rho_xy",
    "rho_x_heading",
    "rho_y_heading",
)


# While the bumper is pressed, how many steps of unknown motion the position variance keeps
# growing quadratically for (a constant unknown velocity), before it grows linearly.
CONTACT_CORRELATION_STEPS = 10


def contact_variance(distance: np.ndarray, steps_in_contact: np.ndarray) -> np.ndarray:
    """Position variance (per axis, m^2) to add in a step spent pressed against something.

    Pushing into an obstacle, the wheels turn (the odometry reports the commanded
    ``distance``) while the robot moves anywhere between not at all and that far
    (sliding along the obstacle). The prediction takes no translation, and the
    unknown motion is a velocity that stays the same while the contact lasts:
    after ``k`` steps its error is up to ``k * distance``, so step ``k`` adds
    ``(2k - 1) distance^2`` (``k`` capped at :data:`CONTACT_CORRELATION_STEPS`).
    """
    k = np.minimum(steps_in_contact, CONTACT_CORRELATION_STEPS)
    return (2 * k - 1) * distance * distance


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
        odo, dt_sub = _team_odometry(cfg, readings, g, active, self._whole_team)
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


def make_backends(cfg: ScenarioConfig, world: World) -> list[EstimatorBackend]:
    """One backend per estimator type used by the team.

    A backend class is called as ``cls(cfg, robots, world)`` (``world`` gives
    the known map, e.g. for particle filters; estimators never read the truth).
    """
    by_type: dict[str, list[int]] = {}
    for i in range(cfg.n_robots):
        by_type.setdefault(cfg.robot_spec(i).estimator, []).append(i)
    return [backend_class(name)(cfg, np.array(robots), world)
            for name, robots in by_type.items()]

