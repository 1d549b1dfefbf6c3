"""Replay logged multi-robot data through the estimators and score them against ground truth.

Standard protocol (MR.CLAM): start at the latest odometry start of the
robots, initialize each robot at its ground-truth pose there, run through the
time-sorted stream of all robots' measurements (odometry is integrated
between events), and evaluate on a 1 s grid against ground truth interpolated
at the grid times (grid times without ground truth are skipped). Heading is
always estimated, never read from ground truth.

Estimators: ``dead_reckoning`` (odometry only), ``ekf`` (independent
per-robot EKFs with landmark updates), ``ekf_team`` (centralized team EKF that
also fuses robot-to-robot range-bearing measurements). ``use_landmarks=False``
keeps only robot-to-robot measurements.

Noise parameters (:class:`NoiseParameters`) are fitted from one dataset's
ground truth by :func:`fit_noise_parameters` and stored as JSON; the package
ships one fitted on MR.CLAM dataset 6 *outside* the standard evaluation window
(see ``estimators/data/mrclam_noise.json``, field ``fitted_on``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from estimators.geometry import wrap_angle
from estimators.mrclam import MrclamDataset, interpolate_groundtruth
from estimators.team_ekf import MotionNoise, OdometryTrack, TeamEKF

__all__ = [
    "ESTIMATORS",
    "DEFAULT_NOISE_PATH",
    "NoiseParameters",
    "ReplayResult",
    "evaluate",
    "fit_noise_parameters",
    "load_noise_parameters",
    "replay",
    "save_noise_parameters",
]

ESTIMATORS = ("dead_reckoning", "ekf", "ekf_team", "mle")
DEFAULT_NOISE_PATH = Path(__file__).resolve().parent / "data" / "mrclam_noise.json"


@dataclass(frozen=True)
class NoiseParameters:
    """Calibration and noise of the motion and measurement models (SI units).

    Motion: commands are delayed by ``odometry_delay_s`` and scaled by
    ``v_scale``/``w_scale``; noise densities ``q = q0 + q1 * |command|``
    (:class:`~estimators.team_ekf.MotionNoise`). Measurements: a reading
    stamped ``t`` refers to time ``t - measurement_delay_s``; range and
    bearing biases are subtracted; the standard deviations are
    ``range_std_a + range_std_b * range`` and ``bearing_std`` (separately for
    landmark and robot targets). ``gate_prob`` is the chi-square gate
    probability; ``initial_std_xy``/``initial_std_heading`` the prior around
    the initial ground-truth pose.
    """

    odometry_delay_s: float = 0.0
    v_scale: float = 1.0
    w_scale: float = 1.0
    q_v0: float = 1e-4
    q_v1: float = 0.0
    q_w0: float = 1e-3
    q_w1: float = 0.0
    measurement_delay_s: float = 0.0
    range_bias_m: float = 0.0
    bearing_bias_rad: float = 0.0
    landmark_range_std_a: float = 0.05
    landmark_range_std_b: float = 0.03
    landmark_bearing_std: float = 0.01
    robot_range_std_a: float = 0.05
    robot_range_std_b: float = 0.03
    robot_bearing_std: float = 0.01
    gate_prob: float = 0.99
    initial_std_xy: float = 0.01
    initial_std_heading: float = 0.01
    fitted_on: str = ""

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "fitted_on":
                continue
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ValueError(f"NoiseParameters.{f.name} must be a finite number, got {value!r}")
        for name in ("v_scale", "w_scale", "landmark_bearing_std", "robot_bearing_std"):
            if getattr(self, name) <= 0:
                raise ValueError(f"NoiseParameters.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.gate_prob < 1.0:
            raise ValueError(f"NoiseParameters.gate_prob must be in (0, 1), got {self.gate_prob!r}")

    @property
    def motion_noise(self) -> MotionNoise:
        """The process-noise model for :class:`OdometryTrack`."""
        return MotionNoise(self.q_v0, self.q_v1, self.q_w0, self.q_w1)

    def measurement_cov(self, rng: float, robot_target: bool) -> np.ndarray:
        """2x2 range-bearing covariance for a reading at range ``rng``."""
        if robot_target:
            sr = self.robot_range_std_a + self.robot_range_std_b * rng
            sb = self.robot_bearing_std
        else:
            sr = self.landmark_range_std_a + self.landmark_range_std_b * rng
            sb = self.landmark_bearing_std
        sr = max(sr, 1e-3)
        return np.array([[sr * sr, 0.0], [0.0, sb * sb]])


def save_noise_parameters(params: NoiseParameters, path: str | Path) -> None:
    """Write ``params`` as JSON."""
    Path(path).write_text(json.dumps(asdict(params), indent=2) + "\n")


def load_noise_parameters(path: str | Path | None = None) -> NoiseParameters:
    """Read parameters written by :func:`save_noise_parameters` (default: the shipped file)."""
    p = Path(path) if path is not None else DEFAULT_NOISE_PATH
    if not p.is_file():
        raise FileNotFoundError(f"noise parameter file not found: {p}")
    try:
        raw = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc})") from None
    known = {f.name for f in fields(NoiseParameters)}
    unknown = set(raw) - known
    if unknown:
        raise ValueError(f"{p}: unknown noise parameter(s) {sorted(unknown)}")
    return NoiseParameters(**raw)


@dataclass
class ReplayResult:
    """Estimates and ground truth of one replay on the evaluation grid.

    ``estimate``/``truth``: ``(R, G, 3)``; ``cov``: ``(R, G, 3, 3)``;
    ``valid``: ``(R, G)`` (ground truth available); counts per robot.
    """

    estimator: str
    robot_ids: list[int]
    times: np.ndarray
    estimate: np.ndarray
    cov: np.ndarray
    truth: np.ndarray
    valid: np.ndarray
    accepted: np.ndarray
    rejected: np.ndarray
    runtime_s: float
    info: dict = field(default_factory=dict)


def _build_tracks(dataset: MrclamDataset, params: NoiseParameters) -> list[OdometryTrack]:
    noise = params.motion_noise
    return [
        OdometryTrack(
            log.odometry[:, 0],
            log.odometry[:, 1],
            log.odometry[:, 2],
            noise,
            delay=params.odometry_delay_s,
            v_scale=params.v_scale,
            w_scale=params.w_scale,
        )
        for log in (dataset.robots[r] for r in dataset.robot_ids)
    ]


def _measurement_stream(
    dataset: MrclamDataset, params: NoiseParameters, t_start: float, t_end: float
) -> np.ndarray:
    """Rows ``t, robot_index, subject, range, bearing`` of all robots, sorted by time."""
    rows = []
    for idx, rid in enumerate(dataset.robot_ids):
        m = dataset.robots[rid].measurements
        t = m[:, 0] - params.measurement_delay_s
        rows.append(np.column_stack([t, np.full(len(m), idx), m[:, 1:4]]))
    allm = np.concatenate(rows) if rows else np.zeros((0, 5))
    allm = allm[(allm[:, 0] > t_start) & (allm[:, 0] <= t_end)]
    return allm[np.argsort(allm[:, 0], kind="stable")]


def replay(
    dataset: MrclamDataset,
    estimator: str,
    params: NoiseParameters,
    duration: float = 600.0,
    use_landmarks: bool = True,
    start_offset: float = 0.0,
    grid_step: float = 1.0,
    progress: Callable[[float], None] | None = None,
) -> ReplayResult:
    """Run ``estimator`` on ``dataset`` with the standard protocol (see module doc).

    ``start_offset`` shifts the start after the latest odometry start (to
    evaluate on other time spans); ``progress`` is called with the fraction
    of the run done. Raises ``ValueError`` for an unknown estimator or a
    non-positive duration, and when the window has no ground truth.
    """
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}; choose one of {ESTIMATORS}")
    if estimator == "mle":
        raise ValueError(
            "estimator 'mle' is not available for log replay: no pose-graph MLE module "
            "(estimators.pose_graph / estimators.mle_online) with a usable API exists yet"
        )
    if not duration > 0:
        raise ValueError(f"duration must be > 0, got {duration!r}")
    if not grid_step > 0:
        raise ValueError(f"grid_step must be > 0, got {grid_step!r}")
    if not start_offset >= 0:
        raise ValueError(f"start_offset must be >= 0, got {start_offset!r}")
    wall = time.perf_counter()
    ids = dataset.robot_ids
    t0 = dataset.latest_odometry_start() + start_offset
    t_end = t0 + duration
    grid = t0 + grid_step * np.arange(1, int(np.floor(duration / grid_step + 1e-9)) + 1)
    truth = np.zeros((len(ids), len(grid), 3))
    valid = np.zeros((len(ids), len(grid)), dtype=bool)
    init = np.zeros((len(ids), 3))
    for i, rid in enumerate(ids):
        truth[i], valid[i] = interpolate_groundtruth(dataset.robots[rid].groundtruth, grid)
        p0, ok = interpolate_groundtruth(dataset.robots[rid].groundtruth, np.array([t0]))
        if not ok[0]:
            raise ValueError(f"robot {rid} has no ground truth at the start time {t0:.3f} s")
        init[i] = p0[0]
    if not valid.any():
        raise ValueError(f"no ground truth in the evaluation window [{t0:.3f}, {t_end:.3f}] s")

    cov0 = np.diag([params.initial_std_xy**2] * 2 + [params.initial_std_heading**2])
    ekf = TeamEKF(
        _build_tracks(dataset, params),
        init,
        cov0,
        t0,
        gate_prob=params.gate_prob,
        cooperative=estimator == "ekf_team",
    )
    if estimator == "dead_reckoning":
        stream = np.zeros((0, 5))
    else:
        stream = _measurement_stream(dataset, params, t0, t_end)
        if not use_landmarks:
            stream = stream[~np.isin(stream[:, 2], list(dataset.landmarks))]
        if estimator == "ekf":
            stream = stream[np.isin(stream[:, 2], list(dataset.landmarks))]
    subj_index = {rid: i for i, rid in enumerate(ids)}
    est = np.zeros((len(ids), len(grid), 3))
    cov = np.zeros((len(ids), len(grid), 3, 3))

    def record(g: int) -> None:
        for i in range(len(ids)):
            ekf.predict_to(i, grid[g])
            a = 3 * i
            est[i, g] = ekf.x[a : a + 3]
            cov[i, g] = ekf.P[a : a + 3, a : a + 3]

    g = 0
    n_events = len(stream)
    report_every = max(1, n_events // 100)
    for e in range(n_events):
        t, ri, subject, rng, bearing = stream[e]
        while g < len(grid) and grid[g] <= t:
            record(g)
            g += 1
        i = int(ri)
        z = np.array([rng - params.range_bias_m, wrap_angle(bearing - params.bearing_bias_rad)])
        s = int(subject)
        if s in subj_index:
            ekf.update_robot(i, subj_index[s], z, params.measurement_cov(rng, True), t)
        else:
            ekf.update_landmark(i, dataset.landmarks[s], z, params.measurement_cov(rng, False), t)
        if progress is not None and e % report_every == 0:
            progress(e / max(n_events, 1))
    while g < len(grid):
        record(g)
        g += 1
    if progress is not None:
        progress(1.0)
    runtime = time.perf_counter() - wall
    return ReplayResult(
        estimator=estimator,
        robot_ids=list(ids),
        times=grid,
        estimate=est,
        cov=cov,
        truth=truth,
        valid=valid,
        accepted=ekf.accepted.copy(),
        rejected=ekf.rejected.copy(),
        runtime_s=runtime,
        info={
            "start_time_s": t0,
            "duration_s": duration,
            "use_landmarks": use_landmarks,
            "measurements_in_window": int(n_events),
        },
    )


def evaluate(result: ReplayResult) -> dict:
    """Per-robot and mean metrics of a replay (the JSON layout of ``scripts/replay_logs.py``).

    Per robot, over the valid grid times: ``mean_position_error_m``,
    ``position_rmse_m``, ``mean_heading_error_deg`` (absolute), ``final_position_error_m``
    (last valid grid time), ``nees_95_fraction`` (fraction of times the true
    position lies inside the 95 % ellipse of the position covariance),
    ``rejected_measurements`` (gated out). Top-level values are the means over
    robots (``rejected_measurements`` the total); ``pooled_position_rmse_m``
    is the RMSE over all robots' errors together.
    """
    gate95 = float(chi2.ppf(0.95, 2))
    per_robot = []
    pooled_sq = []
    for i, rid in enumerate(result.robot_ids):
        ok = result.valid[i]
        if not ok.any():
            continue
        d = result.estimate[i, ok, :2] - result.truth[i, ok, :2]
        err = np.hypot(d[:, 0], d[:, 1])
        herr = np.abs(wrap_angle(result.estimate[i, ok, 2] - result.truth[i, ok, 2]))
        c = result.cov[i, ok, :2, :2]
        nees = np.einsum("ti,tij,tj->t", d, np.linalg.inv(c), d)
        pooled_sq.append(err**2)
        per_robot.append(
            {
                "robot": int(rid),
                "mean_position_error_m": float(err.mean()),
                "position_rmse_m": float(np.sqrt(np.mean(err**2))),
                "mean_heading_error_deg": float(np.degrees(herr.mean())),
                "final_position_error_m": float(err[-1]),
                "nees_95_fraction": float(np.mean(nees <= gate95)),
                "rejected_measurements": int(result.rejected[i]),
                "accepted_measurements": int(result.accepted[i]),
                "evaluated_times": int(ok.sum()),
            }
        )
    if not per_robot:
        raise ValueError("no robot has ground truth on the evaluation grid")

    def mean(key: str) -> float:
        return float(np.mean([r[key] for r in per_robot]))

    return {
        "estimator": result.estimator,
        "use_landmarks": bool(result.info.get("use_landmarks", True)),
        "duration_s": float(result.info.get("duration_s", np.nan)),
        "mean_position_error_m": mean("mean_position_error_m"),
        "position_rmse_m": mean("position_rmse_m"),
        "pooled_position_rmse_m": float(np.sqrt(np.mean(np.concatenate(pooled_sq)))),
        "mean_heading_error_deg": mean("mean_heading_error_deg"),
        "final_position_error_m": mean("final_position_error_m"),
        "nees_95_fraction": mean("nees_95_fraction"),
        "rejected_measurements": int(sum(r["rejected_measurements"] for r in per_robot)),
        "accepted_measurements": int(sum(r["accepted_measurements"] for r in per_robot)),
        "runtime_s": float(result.runtime_s),
        "per_robot": per_robot,
    }
