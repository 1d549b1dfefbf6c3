"""What every estimation backend is: the base class, the shared Gaussian features, the
noisy start, the team's odometry, and building a team's backends.

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

from coop_loc_env._step_kernels import gaussian_rows
from coop_loc_env.backends import backend_class
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.records import Beliefs
from coop_loc_env.sensors import Readings
from coop_loc_env.world import World


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
    odo, dt_sub = stacked_team_odometry(cfg, readings, robots, active, whole_team)
    return odo[..., 0], odo[..., 1], dt_sub


def stacked_team_odometry(
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

