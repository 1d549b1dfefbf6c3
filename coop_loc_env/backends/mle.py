"""Estimator backend ``"mle"``: team localization by maximum likelihood (Howard et al.).

One :class:`~estimators.mle_online.TeamMLE` (a sliding-window pose graph) is
shared by all robots that use ``estimator="mle"``: it is **centralized**, as in
the paper, where every robot's odometry and robot detections go to one
optimizer. Each step it receives the robots' odometry (motion factors over
``motion_window`` seconds) and every detection between two of its robots (range,
bearing and orientation with the detector's covariance), and re-optimizes.
GPS, compass and the range finder are not used (Howard et al. have neither GPS
nor landmarks).

**Global frame.** Howard et al.'s formulation fixes no absolute frame: only
relative poses are determined by the data. The gauge is fixed by anchoring one
robot (``anchoring = "one_robot"``): the backend's first robot gets a Gaussian
prior on its start pose, centred at the noisy start the env gives every
estimator (std ``init_pos_std``, ``init_pos_std``, ``init_heading_std``), so
that the absolute ``position_error`` and ``heading_error`` of the infos stay
meaningful. The other robots' start poses are free: their priors
(:data:`~estimators.mle_online.UNKNOWN_POSE_STD`, 1 km and pi rad) only keep a
robot no teammate has seen yet well posed, and move relative poses by about
``(sigma_data / 1 km)^2`` of themselves, so the relative metrics (Eq. 15) are set
by the odometry and the detections alone.

**Window.** ``extras["mle_window"]`` keyframes per robot stay in the
optimization (default 5, about 5 s when robots see each other), older ones are
marginalized; ``None`` solves the whole graph at every step (the paper's batch
problem, cost growing with the episode). ``extras["mle_keyframe_interval"]``
(s, default 1) is the odometry a robot integrates before an observation starts
a fresh keyframe for it; ``0`` gives every observation its own nodes, at its own
time, as in the paper's graph; ``None``: keyframes only every ``MOTION_WINDOW_S``
(10 s, the paper's sampled times), observations attached to them through the
odometry since. ``extras["mle_keep_history"] = True`` also records
the whole graph (``backend.mle.history``) whatever the window, e.g. to re-solve
it offline or hand it to another solver.

**Features** (``feature_names``): the Gaussian belief of the robot's latest pose
(:func:`~coop_loc_env.backends.base.gaussian_features`, 10 entries), then its
estimated relative poses to its ``K`` nearest teammates by *estimated* distance
(``K = cfg.extras.get("mle_relative_slots", 3)``), nearest first, 6 entries per
slot: present (0/1), range / ``detector_range``, cos/sin bearing, cos/sin
orientation of the teammate in the robot's estimated frame. Slots beyond the
number of teammates are zero.

**Infos**: :meth:`MLEBackend.extra_info` adds ``relative_range_error`` (m),
``relative_bearing_error`` and ``relative_orientation_error`` (rad) per robot:
the mean absolute error of its estimated relative poses to all teammates of the
backend (Eq. 15 restricted to row ``a``). :func:`relative_error_infos` computes
the same for any estimator's means.
"""

from __future__ import annotations

import numpy as np

from coop_loc_env.backends.base import (
    GAUSSIAN_FEATURE_NAMES,
    EstimatorBackend,
    gaussian_features,
    noisy_start,
    team_odometry,
)
from coop_loc_env.backends.mle_options import check_extra
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.sensors import Readings
from coop_loc_env.world import World
from estimators.mle_online import UNKNOWN_POSE_STD, TeamMLE
from estimators.relative_metrics import (
    ERROR_NAMES,
    relative_errors_per_robot,
    relative_pose_matrix,
)

DEFAULT_RELATIVE_SLOTS = 3
RELATIVE_FIELDS = ("present", "range", "cos_bearing", "sin_bearing", "cos_orient", "sin_orient")
MOTION_WINDOW_S = 10.0  # odometry integrated into one motion factor (Howard et al.)
WINDOW_KEYFRAMES = 5  # keyframes per robot kept in the optimization window (>= 5 s)
KEYFRAME_INTERVAL_S = 1.0  # odometry (s) before an observation starts fresh keyframes
ANCHORING = "one_robot"  # how the gauge is fixed (see the module docstring)


def relative_slots(cfg: ScenarioConfig) -> int:
    """Number of teammate slots ``K`` in the relative-pose block (``extras``)."""
    k = cfg.extras.get("mle_relative_slots", DEFAULT_RELATIVE_SLOTS)
    check_extra("mle_relative_slots", k)
    return k


def window_options(cfg: ScenarioConfig) -> tuple[int | None, float | None]:
    """``(window, keyframe_interval)`` from ``extras`` (see the module docstring)."""
    window = cfg.extras.get("mle_window", WINDOW_KEYFRAMES)
    check_extra("mle_window", window)
    interval = cfg.extras.get("mle_keyframe_interval", KEYFRAME_INTERVAL_S)
    check_extra("mle_keyframe_interval", interval)
    return window, None if interval is None else float(interval)


def relative_pose_features(poses: np.ndarray, slots: int, range_scale: float) -> np.ndarray:
    """Each robot's estimated relative poses to its ``slots`` nearest teammates, ``(k, 6*slots)``.

    ``poses`` ``(k, 3)`` are estimated poses in a common frame. Per slot,
    nearest first: present, range / ``range_scale``, cos/sin bearing, cos/sin
    orientation (see the module docstring); missing teammates give zeros.
    """
    poses = np.asarray(poses, dtype=float)
    k = len(poses)
    out = np.zeros((k, slots, 6))
    m = min(slots, k - 1)
    if m > 0:
        rel = relative_pose_matrix(poses)  # (k, k, 3)
        dist = rel[..., 0].copy()
        dist[np.arange(k), np.arange(k)] = np.inf
        order = np.argsort(dist, axis=1, kind="stable")[:, :m]  # (k, m)
        sel = np.take_along_axis(rel, order[..., None], axis=1)  # (k, m, 3)
        out[:, :m, 0] = 1.0
        out[:, :m, 1] = sel[..., 0] / range_scale
        out[:, :m, 2] = np.cos(sel[..., 1])
        out[:, :m, 3] = np.sin(sel[..., 1])
        out[:, :m, 4] = np.cos(sel[..., 2])
        out[:, :m, 5] = np.sin(sel[..., 2])
    return out.reshape(k, 6 * slots)


def relative_feature_names(slots: int) -> tuple[str, ...]:
    """Names of the relative-pose block: ``mate{j}_{field}`` for each slot ``j``."""
    return tuple(f"mate{j}_{f}" for j in range(slots) for f in RELATIVE_FIELDS)


def relative_error_infos(
    est_poses: np.ndarray, true_poses: np.ndarray, robots: np.ndarray
) -> dict[int, dict[str, float]]:
    """Eq. 15 errors of each robot's view of its teammates, keyed by global robot index.

    ``est_poses`` and ``true_poses`` are ``(k, 3)`` for the global indices
    ``robots`` (``(k,)``). Returns ``{}`` with fewer than two robots.
    Usable by any estimator (e.g. the env's infos for every backend).
    """
    robots = np.asarray(robots, dtype=int)
    if len(robots) < 2:
        return {}
    per = relative_errors_per_robot(est_poses, true_poses)
    return {
        int(g): {name: float(v) for name, v in zip(ERROR_NAMES, per[i], strict=True)}
        for i, g in enumerate(robots)
    }


class MLEBackend(EstimatorBackend):
    """Centralized sliding-window MLE (Howard et al.) for the robots in ``robots``.

    See the module docstring for the frame, the features and the infos.
    """

    def __init__(self, cfg: ScenarioConfig, robots: np.ndarray, world: World | None = None) -> None:
        self.cfg = cfg
        self.robots = np.asarray(robots, dtype=int)
        self._local = {int(g): i for i, g in enumerate(self.robots)}
        self.slots = relative_slots(cfg)
        self.window, self.keyframe_interval = window_options(cfg)
        self.feature_size = len(GAUSSIAN_FEATURE_NAMES) + 6 * self.slots
        self.feature_names = GAUSSIAN_FEATURE_NAMES + relative_feature_names(self.slots)
        self.mle: TeamMLE | None = None

    def reset(self, true_poses: np.ndarray, rng: np.random.Generator) -> None:
        """A fresh pose graph anchored by a prior on the first robot's (noisy) start."""
        cfg = self.cfg
        start, std = noisy_start(cfg, true_poses, self.robots, rng)
        stds = np.tile(np.asarray(UNKNOWN_POSE_STD, dtype=float), (len(self.robots), 1))
        stds[0] = std
        self.mle = TeamMLE(
            len(self.robots),
            initial_poses=start,
            initial_std=stds,
            anchor=None,
            odometry_std=(cfg.odom_v_std, cfg.odom_w_std),
            motion_window=MOTION_WINDOW_S,
            window=self.window,
            keyframe_interval=self.keyframe_interval,
            keep_history=cfg.extras.get("mle_keep_history", False),
            gate_prob=cfg.gate_prob if cfg.gate_prob < 1.0 else None,
        )
        self._cache: tuple[np.ndarray, np.ndarray] | None = None

    def step(self, readings: Readings, active: np.ndarray) -> dict[str, int]:
        """Feed one env step of odometry and detections, then re-optimize."""
        cfg = self.cfg
        g = self.robots
        act = active[g]
        v, w, dt_sub = team_odometry(cfg, readings, g, active)
        self.mle.add_odometry_team(
            v, w, dt_sub,
            std_v=np.hypot(cfg.odom_v_std, cfg.slip_std * v),
            std_w=np.hypot(cfg.odom_w_std, cfg.slip_std * w),
        )
        stats = {"accepted": 0, "rejected": 0, "cooperative": 0}
        det = readings.detections
        gated = self.mle.n_gated
        for k in range(len(det)):
            a, b = self._local.get(int(det.observer[k])), self._local.get(int(det.target[k]))
            if a is None or b is None or not (act[a] and act[b]):
                continue
            if not self.mle.observation_due(a, b):
                continue  # rate-limited anyway: skip the validation
            if self.mle.add_observation(a, b, det.z[k], cov=det.cov[k]):
                stats["cooperative"] += 1
        stats["rejected"] += self.mle.n_gated - gated
        stats["accepted"] = stats["cooperative"]
        self.mle.step()
        self._cache = None
        return stats

    def _belief(self) -> tuple[np.ndarray, np.ndarray]:
        if self._cache is None:
            self._cache = (self.mle.poses(), self.mle.covariances())
        return self._cache

    def mean(self) -> np.ndarray:
        """Estimated latest poses ``(k, 3)``."""
        return self._belief()[0]

    def cov(self) -> np.ndarray:
        """Marginal covariances of the latest poses ``(k, 3, 3)``."""
        return self._belief()[1]

    def features(self) -> np.ndarray:
        """Gaussian belief plus relative poses to the nearest teammates, ``(k, feature_size)``."""
        mean, cov = self._belief()
        own = gaussian_features(mean, cov, self.cfg.world_size)
        rel = relative_pose_features(mean, self.slots, self.cfg.detector_range)
        return np.concatenate([own, rel], axis=1)

    def extra_info(self, true_poses: np.ndarray) -> dict[int, dict[str, float]]:
        """Eq. 15 relative errors per robot (uses the truth: logging only)."""
        return relative_error_infos(self.mean(), true_poses[self.robots], self.robots)

