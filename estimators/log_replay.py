"""Replay logged multi-robot data through the estimators and score them against ground truth.

Standard protocol (MR.CLAM): start at the latest odometry start of the
robots, initialize each robot at its ground-truth pose there, run through the
time-sorted stream of all robots' measurements (odometry is integrated
between events), and evaluate on a 1 s grid against ground truth interpolated
at the grid times (grid times without ground truth are skipped). Heading is
always estimated, never read from ground truth.

Estimators: ``dead_reckoning`` (odometry only), ``ekf`` (independent
per-robot EKFs with landmark updates), ``ekf_team`` (centralized team EKF that
also fuses robot-to-robot range-bearing measurements), ``mle`` (the online
sliding-window pose-graph MLE of :mod:`estimators.mle_online`, landmarks as
fixed nodes). ``use_landmarks=False`` keeps only robot-to-robot measurements.

Noise parameters (:class:`NoiseParameters`) are fitted from one dataset's
ground truth by :func:`fit_noise_parameters` and stored as JSON; the package
ships one fitted on MR.CLAM dataset 6 *outside* the standard evaluation window
(see ``estimators/data/mrclam_noise.json``, field ``fitted_on``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
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
    "scale_noise",
    "tune_inflation",
]

ESTIMATORS = ("dead_reckoning", "ekf", "ekf_team", "mle")
DEFAULT_NOISE_PATH = Path(__file__).resolve().parent / "data" / "mrclam_noise.json"


PER_ROBOT_KEYS = ("v_scale", "w_scale", "bearing_bias_rad", "sensor_x_m", "sensor_y_m")


@dataclass(frozen=True)
class NoiseParameters:
    """Calibration and noise of the motion and measurement models (SI units).

    Motion: commands are delayed by ``odometry_delay_s`` and scaled by
    ``v_scale``/``w_scale``; noise densities ``q = q0 + q1 * |command|``
    (:class:`~estimators.team_ekf.MotionNoise`). Measurements: a reading
    stamped ``t`` refers to time ``t - measurement_delay_s``; range and
    bearing biases are subtracted; the standard deviations are
    ``range_std_a + range_std_b * range`` and ``bearing_std`` (separately for
    landmark and robot targets); the sensor sits at ``(sensor_x_m,
    sensor_y_m)`` in the body frame. ``per_robot`` maps a robot number (as a
    string) to overrides of any of :data:`PER_ROBOT_KEYS` (a per-robot
    calibration; empty = global parameters only). ``gate_prob`` is the chi-square gate
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
    sensor_x_m: float = 0.0
    sensor_y_m: float = 0.0
    gate_prob: float = 0.99
    initial_std_xy: float = 0.01
    initial_std_heading: float = 0.01
    per_robot: dict = field(default_factory=dict)
    fitted_on: str = ""

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name in ("fitted_on", "per_robot"):
                continue
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ValueError(f"NoiseParameters.{f.name} must be a finite number, got {value!r}")
        for name in ("v_scale", "w_scale", "landmark_bearing_std", "robot_bearing_std"):
            if getattr(self, name) <= 0:
                raise ValueError(f"NoiseParameters.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.gate_prob < 1.0:
            raise ValueError(f"NoiseParameters.gate_prob must be in (0, 1), got {self.gate_prob!r}")
        for rid, over in self.per_robot.items():
            if not str(rid).isdigit() or not isinstance(over, dict):
                raise ValueError(f"NoiseParameters.per_robot: bad entry {rid!r}: {over!r}")
            bad = set(over) - set(PER_ROBOT_KEYS)
            if bad:
                raise ValueError(
                    f"NoiseParameters.per_robot[{rid!r}]: unknown key(s) {sorted(bad)}; "
                    f"allowed: {PER_ROBOT_KEYS}"
                )
            for key, value in over.items():
                if not isinstance(value, (int, float)) or not np.isfinite(value):
                    raise ValueError(
                        f"NoiseParameters.per_robot[{rid!r}][{key!r}] must be finite, got {value!r}"
                    )

    def for_robot(self, robot: int) -> dict[str, float]:
        """The calibration of robot ``robot``: globals overridden by ``per_robot[str(robot)]``."""
        out = {key: float(getattr(self, key)) for key in PER_ROBOT_KEYS}
        out.update(self.per_robot.get(str(robot), {}))
        return out

    def without_per_robot(self) -> NoiseParameters:
        """The same parameters with the per-robot calibration dropped (globals only)."""
        return replace(self, per_robot={})

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
    tracks = []
    for rid in dataset.robot_ids:
        log = dataset.robots[rid]
        cal = params.for_robot(rid)
        tracks.append(
            OdometryTrack(
                log.odometry[:, 0],
                log.odometry[:, 1],
                log.odometry[:, 2],
                noise,
                delay=params.odometry_delay_s,
                v_scale=cal["v_scale"],
                w_scale=cal["w_scale"],
            )
        )
    return tracks


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
        sensor_offset=[
            [params.for_robot(r)["sensor_x_m"], params.for_robot(r)["sensor_y_m"]] for r in ids
        ],
    )
    if estimator == "dead_reckoning":
        stream = np.zeros((0, 5))
    else:
        stream = _measurement_stream(dataset, params, t0, t_end)
        if not use_landmarks:
            stream = stream[~np.isin(stream[:, 2], list(dataset.landmarks))]
        if estimator == "ekf":
            stream = stream[np.isin(stream[:, 2], list(dataset.landmarks))]
    if estimator == "mle":
        est, cov, accepted, rejected = _replay_mle(
            dataset, params, ekf.tracks, init, t0, grid, stream, progress
        )
    else:
        est, cov = _run_ekf(ekf, dataset, params, grid, stream, progress)
        accepted, rejected = ekf.accepted.copy(), ekf.rejected.copy()
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
        accepted=accepted,
        rejected=rejected,
        runtime_s=runtime,
        info={
            "start_time_s": t0,
            "duration_s": duration,
            "use_landmarks": use_landmarks,
            "measurements_in_window": len(stream),
        },
    )


def _run_ekf(
    ekf: TeamEKF,
    dataset: MrclamDataset,
    params: NoiseParameters,
    grid: np.ndarray,
    stream: np.ndarray,
    progress: Callable[[float], None] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Feed the time-sorted ``stream`` to ``ekf``; return the beliefs on ``grid``.

    Shapes ``(R, G, 3)`` and ``(R, G, 3, 3)``.
    """
    ids = dataset.robot_ids
    subj_index = {rid: i for i, rid in enumerate(ids)}
    bearing_bias = [params.for_robot(r)["bearing_bias_rad"] for r in ids]
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
        z = np.array([rng - params.range_bias_m, wrap_angle(bearing - bearing_bias[i])])
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
    return est, cov


def evaluate(result: ReplayResult) -> dict:
    """Per-robot and mean metrics of a replay (the JSON layout of ``scripts/replay_logs.py``).

    Per robot, over the valid grid times: ``mean_position_error_m``,
    ``position_rmse_m``, ``mean_heading_error_deg`` (absolute), ``final_position_error_m``
    (last valid grid time), ``nees_95_fraction`` (fraction of times the true
    position lies inside the 95 % ellipse of the position covariance),
    ``rejected_measurements`` (gated out). Top-level values pool all robots'
    grid times (so ``position_rmse_m`` is the RMSE over every robot and time,
    the convention of the dataset README's reference figures), except
    ``final_position_error_m`` (mean over robots), the counts (totals) and
    ``mean_robot_position_rmse_m`` (mean of the per-robot RMSEs).
    """
    gate95 = float(chi2.ppf(0.95, 2))
    per_robot = []
    pooled: dict[str, list[np.ndarray]] = {"err": [], "herr": [], "inside": []}
    for i, rid in enumerate(result.robot_ids):
        ok = result.valid[i]
        if not ok.any():
            continue
        d = result.estimate[i, ok, :2] - result.truth[i, ok, :2]
        err = np.hypot(d[:, 0], d[:, 1])
        herr = np.abs(wrap_angle(result.estimate[i, ok, 2] - result.truth[i, ok, 2]))
        c = result.cov[i, ok, :2, :2]
        inside = np.einsum("ti,tij,tj->t", d, np.linalg.inv(c), d) <= gate95
        pooled["err"].append(err)
        pooled["herr"].append(herr)
        pooled["inside"].append(inside)
        per_robot.append(
            {
                "robot": int(rid),
                "mean_position_error_m": float(err.mean()),
                "position_rmse_m": float(np.sqrt(np.mean(err**2))),
                "mean_heading_error_deg": float(np.degrees(herr.mean())),
                "final_position_error_m": float(err[-1]),
                "nees_95_fraction": float(np.mean(inside)),
                "rejected_measurements": int(result.rejected[i]),
                "accepted_measurements": int(result.accepted[i]),
                "evaluated_times": int(ok.sum()),
            }
        )
    if not per_robot:
        raise ValueError("no robot has ground truth on the evaluation grid")
    err = np.concatenate(pooled["err"])
    herr = np.concatenate(pooled["herr"])
    inside = np.concatenate(pooled["inside"])
    return {
        "estimator": result.estimator,
        "use_landmarks": bool(result.info.get("use_landmarks", True)),
        "duration_s": float(result.info.get("duration_s", np.nan)),
        "mean_position_error_m": float(err.mean()),
        "position_rmse_m": float(np.sqrt(np.mean(err**2))),
        "mean_robot_position_rmse_m": float(np.mean([r["position_rmse_m"] for r in per_robot])),
        "mean_heading_error_deg": float(np.degrees(herr.mean())),
        "final_position_error_m": float(np.mean([r["final_position_error_m"] for r in per_robot])),
        "nees_95_fraction": float(np.mean(inside)),
        "rejected_measurements": int(sum(r["rejected_measurements"] for r in per_robot)),
        "accepted_measurements": int(sum(r["accepted_measurements"] for r in per_robot)),
        "runtime_s": float(result.runtime_s),
        "per_robot": per_robot,
    }


def _mad_std(e: np.ndarray) -> float:
    """Robust standard deviation (1.4826 * median absolute deviation)."""
    return float(1.4826 * np.median(np.abs(e - np.median(e))))


def _motion_windows(
    dataset: MrclamDataset, rid: int, t_start: float, t_end: float, width: float, lag: float
) -> np.ndarray:
    """Commanded vs ground-truth velocities over consecutive windows of ``width`` seconds.

    Rows ``cmd_v, cmd_w, cmd_abs_v, cmd_abs_w, gt_v, gt_w`` (window averages;
    ground truth taken ``lag`` seconds later than the commands).
    """
    log = dataset.robots[rid]
    o = log.odometry
    lo = max(t_start, o[0, 0])
    starts = np.arange(lo, t_end - width - lag, width)
    if starts.size == 0:
        return np.zeros((0, 6))
    dt = np.diff(o[:, 0])
    cum = np.zeros((len(o), 4))
    cum[1:] = np.cumsum(
        np.column_stack([o[:-1, 1], o[:-1, 2], np.abs(o[:-1, 1]), np.abs(o[:-1, 2])]) * dt[:, None],
        axis=0,
    )

    def integral(t: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(o[:, 0], t, side="right") - 1, 0, len(o) - 1)
        tau = np.clip(t - o[k, 0], 0.0, None)
        rate = np.column_stack([o[k, 1], o[k, 2], np.abs(o[k, 1]), np.abs(o[k, 2])])
        return cum[k] + tau[:, None] * rate

    cmd = (integral(starts + width) - integral(starts)) / width
    pa, va = interpolate_groundtruth(log.groundtruth, starts + lag)
    pb, vb = interpolate_groundtruth(log.groundtruth, starts + width + lag)
    ok = va & vb
    dh = wrap_angle(pb[:, 2] - pa[:, 2])
    mid = pa[:, 2] + 0.5 * dh
    d = pb[:, :2] - pa[:, :2]
    gv = (d[:, 0] * np.cos(mid) + d[:, 1] * np.sin(mid)) / width
    gw = dh / width
    return np.column_stack([cmd, gv, gw])[ok]


def _measurement_residual_table(
    dataset: MrclamDataset, t_start: float, t_end: float, delay: float
) -> np.ndarray:
    """Rows ``robot, robot_target, t, meas_r, meas_b, local_x, local_y, gt_w, subject``.

    ``local_x/y`` is the ground-truth target position in the observer's body frame at
    ``t - delay``; ``gt_w`` the observer's true turn rate there.
    """
    rows = []
    for rid in dataset.robot_ids:
        log = dataset.robots[rid]
        m = log.measurements
        m = m[(m[:, 0] >= t_start) & (m[:, 0] <= t_end)]
        t = m[:, 0] - delay
        pose, ok = interpolate_groundtruth(log.groundtruth, t)
        pa, oka = interpolate_groundtruth(log.groundtruth, t - 0.1)
        pb, okb = interpolate_groundtruth(log.groundtruth, t + 0.1)
        ok &= oka & okb
        target = np.full((len(m), 2), np.nan)
        is_robot = np.isin(m[:, 1], dataset.robot_ids)
        for s in np.unique(m[:, 1]).astype(int):
            sel = m[:, 1] == s
            if s in dataset.landmarks:
                target[sel] = dataset.landmarks[s]
            else:
                p, v = interpolate_groundtruth(dataset.robots[s].groundtruth, t[sel])
                p[~v] = np.nan
                target[sel] = p[:, :2]
        ok &= np.all(np.isfinite(target), axis=1)
        c, s_ = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        d = target - pose[:, :2]
        lx = c * d[:, 0] + s_ * d[:, 1]
        ly = -s_ * d[:, 0] + c * d[:, 1]
        gw = wrap_angle(pb[:, 2] - pa[:, 2]) / 0.2
        rows.append(
            np.column_stack(
                [np.full(len(m), rid), is_robot, t, m[:, 2], m[:, 3], lx, ly, gw, m[:, 1]]
            )[ok]
        )
    return np.concatenate(rows) if rows else np.zeros((0, 9))


def _fit_sensor(tab: np.ndarray, range_bias: float) -> tuple[float, float, float]:
    """Least-squares sensor offset ``(x, y)`` and bearing bias from inlier readings."""
    from scipy.optimize import least_squares

    r_sd = max(_mad_std(tab[:, 3] - np.hypot(tab[:, 5], tab[:, 6])), 1e-3)
    b_sd = max(_mad_std(wrap_angle(tab[:, 4] - np.arctan2(tab[:, 6], tab[:, 5]))), 1e-4)

    def resid(p: np.ndarray) -> np.ndarray:
        dx, dy = tab[:, 5] - p[0], tab[:, 6] - p[1]
        er = (tab[:, 3] - range_bias - np.hypot(dx, dy)) / r_sd
        eb = wrap_angle(tab[:, 4] - p[2] - np.arctan2(dy, dx)) / b_sd
        return np.concatenate([er, eb])

    sol = least_squares(resid, np.zeros(3), loss="soft_l1", f_scale=2.0)
    return float(sol.x[0]), float(sol.x[1]), float(sol.x[2])


def fit_noise_parameters(
    dataset: MrclamDataset,
    t_start: float | None = None,
    t_end: float | None = None,
    per_robot: bool = True,
    tune: bool = True,
) -> NoiseParameters:
    """Estimate calibration and noise from ground truth over ``[t_start, t_end]``.

    Motion: the command-to-motion delay (grid search minimizing the turn-rate
    residual over 1 s windows), the velocity scales (least squares over 4 s
    windows), and the noise densities ``q = q0 + q1 |command|`` (regression of
    squared 1 s-window residuals). Measurements: the time-stamp delay
    (regression of the bearing residual on the true turn rate), the range bias
    (median), the sensor offset and bearing bias (robust least squares), and
    robust (MAD) standard deviations, ``range_std = a + b * range`` (fitted
    over range bins) and ``bearing_std``, for landmark and robot targets.
    With ``per_robot`` the velocity scales, sensor offset and bearing bias
    are also fitted per robot. With ``tune`` the noise is then inflated by
    :func:`tune_inflation` (replays on the same window) to make the filter
    consistent. Times default to the whole log; the window must contain
    ground truth.
    """
    t_start = dataset.latest_odometry_start() if t_start is None else float(t_start)
    t_end = dataset.end_time() if t_end is None else float(t_end)
    if not t_end > t_start:
        raise ValueError(f"fit window is empty: t_start={t_start!r} >= t_end={t_end!r}")
    ids = dataset.robot_ids

    # --- motion: delay, scales, noise densities
    lags = np.arange(0.0, 0.61, 0.02)
    costs = []
    for lag in lags:
        win = np.concatenate([_motion_windows(dataset, r, t_start, t_end, 1.0, lag) for r in ids])
        if len(win) < 10:
            raise ValueError(f"too little ground truth in [{t_start}, {t_end}] to fit motion")
        sw = win[:, 5] @ win[:, 1] / max(win[:, 1] @ win[:, 1], 1e-12)
        costs.append(np.mean((win[:, 5] - sw * win[:, 1]) ** 2))
    lag = float(lags[int(np.argmin(costs))])

    def scales(win: np.ndarray) -> tuple[float, float]:
        sv = win[:, 4] @ win[:, 0] / max(win[:, 0] @ win[:, 0], 1e-12)
        sw = win[:, 5] @ win[:, 1] / max(win[:, 1] @ win[:, 1], 1e-12)
        return float(sv), float(sw)

    long_win = {r: _motion_windows(dataset, r, t_start, t_end, 4.0, lag) for r in ids}
    v_scale, w_scale = scales(np.concatenate(list(long_win.values())))
    robot_scales = {r: scales(long_win[r]) if len(long_win[r]) >= 10 else None for r in ids}
    res_v, res_w = [], []
    for r in ids:
        win = _motion_windows(dataset, r, t_start, t_end, 1.0, lag)
        sv, sw = robot_scales[r] if (per_robot and robot_scales[r]) else (v_scale, w_scale)
        res_v.append(np.column_stack([win[:, 2], (win[:, 4] - sv * win[:, 0]) ** 2 * 1.0]))
        res_w.append(np.column_stack([win[:, 3], (win[:, 5] - sw * win[:, 1]) ** 2 * 1.0]))

    def density(res: np.ndarray) -> tuple[float, float]:
        a = np.column_stack([np.ones(len(res)), res[:, 0]])
        from scipy.optimize import nnls

        coef, _ = nnls(a, res[:, 1])
        return float(coef[0]), float(coef[1])

    q_v0, q_v1 = density(np.concatenate(res_v))
    q_w0, q_w1 = density(np.concatenate(res_w))

    # --- measurements: delay, biases, sensor offset, noise
    tab = _measurement_residual_table(dataset, t_start, t_end, 0.0)
    if len(tab) < 20:
        raise ValueError(f"too few measurements with ground truth in [{t_start}, {t_end}]")
    eb = wrap_angle(tab[:, 4] - np.arctan2(tab[:, 6], tab[:, 5]))
    inl = np.abs(eb - np.median(eb)) < 5 * _mad_std(eb)
    a = np.column_stack([np.ones(inl.sum()), tab[inl, 7]])
    delay = float(np.linalg.lstsq(a, eb[inl], rcond=None)[0][1])
    delay = float(np.clip(delay, 0.0, 0.5))
    tab = _measurement_residual_table(dataset, t_start, t_end, delay)
    er = tab[:, 3] - np.hypot(tab[:, 5], tab[:, 6])
    eb = wrap_angle(tab[:, 4] - np.arctan2(tab[:, 6], tab[:, 5]))
    inl = (np.abs(er - np.median(er)) < 4 * _mad_std(er)) & (
        np.abs(eb - np.median(eb)) < 4 * _mad_std(eb)
    )
    range_bias = float(np.median(er[inl]))
    sx, sy, bb = _fit_sensor(tab[inl], range_bias)
    overrides: dict[str, dict[str, float]] = {}
    sensor = {r: (sx, sy, bb) for r in ids}
    for r in ids:
        if not per_robot:
            continue
        sel = inl & (tab[:, 0] == r)
        entry: dict[str, float] = {}
        if robot_scales[r] is not None:
            entry["v_scale"], entry["w_scale"] = robot_scales[r]
        if sel.sum() >= 30:
            sensor[r] = _fit_sensor(tab[sel], range_bias)
            entry["sensor_x_m"], entry["sensor_y_m"], entry["bearing_bias_rad"] = sensor[r]
        if entry:
            overrides[str(r)] = entry
    # residuals under the fitted sensor model
    cal = np.array([sensor[int(r)] for r in tab[:, 0]])
    dx, dy = tab[:, 5] - cal[:, 0], tab[:, 6] - cal[:, 1]
    rng = np.hypot(dx, dy)
    er = tab[:, 3] - range_bias - rng
    eb = wrap_angle(tab[:, 4] - cal[:, 2] - np.arctan2(dy, dx))

    def noise(sel: np.ndarray) -> tuple[float, float, float]:
        r, e = rng[sel], er[sel]
        edges = np.quantile(r, np.linspace(0, 1, 7))
        mids, sds, ns = [], [], []
        for lo, hi in zip(edges[:-1], edges[1:], strict=True):
            b = (r >= lo) & (r <= hi)
            if b.sum() >= 10:
                mids.append(np.median(r[b]))
                sds.append(_mad_std(e[b]))
                ns.append(b.sum())
        a_mat = np.column_stack([np.ones(len(mids)), mids]) * np.sqrt(ns)[:, None]
        from scipy.optimize import nnls

        coef, _ = nnls(a_mat, np.asarray(sds) * np.sqrt(ns))
        return float(coef[0]), float(coef[1]), _mad_std(eb[sel])

    lm_sel = tab[:, 1] == 0
    rb_sel = tab[:, 1] == 1
    lm_noise = noise(lm_sel)
    rb_noise = noise(rb_sel) if rb_sel.sum() >= 60 else lm_noise
    base = NoiseParameters(
        odometry_delay_s=lag,
        v_scale=v_scale,
        w_scale=w_scale,
        q_v0=q_v0,
        q_v1=q_v1,
        q_w0=q_w0,
        q_w1=q_w1,
        measurement_delay_s=delay,
        range_bias_m=range_bias,
        bearing_bias_rad=bb,
        landmark_range_std_a=lm_noise[0],
        landmark_range_std_b=lm_noise[1],
        landmark_bearing_std=lm_noise[2],
        robot_range_std_a=rb_noise[0],
        robot_range_std_b=rb_noise[1],
        robot_bearing_std=rb_noise[2],
        sensor_x_m=sx,
        sensor_y_m=sy,
        per_robot=overrides,
    )
    where = (
        f"{dataset.path.name} t=[{t_start:.1f}, {t_end:.1f}] s after the first time stamp "
        f"(latest odometry start {dataset.latest_odometry_start():.1f} s); per_robot={per_robot}"
    )
    if not tune:
        return replace(base, fitted_on=where + "; not tuned")
    factors, summary = tune_inflation(dataset, base, t_start, t_end)
    return replace(
        scale_noise(base, *factors),
        fitted_on=where
        + f"; inflation (range, bearing, process) = {factors} tuned on the same window: {summary}",
    )


def scale_noise(
    params: NoiseParameters, range_factor: float, bearing_factor: float, process_factor: float
) -> NoiseParameters:
    """Multiply range and bearing standard deviations and process-noise densities."""
    for name, value in (
        ("range_factor", range_factor),
        ("bearing_factor", bearing_factor),
        ("process_factor", process_factor),
    ):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and > 0, got {value!r}")
    p = params
    return replace(
        p,
        landmark_range_std_a=p.landmark_range_std_a * range_factor,
        landmark_range_std_b=p.landmark_range_std_b * range_factor,
        robot_range_std_a=p.robot_range_std_a * range_factor,
        robot_range_std_b=p.robot_range_std_b * range_factor,
        landmark_bearing_std=p.landmark_bearing_std * bearing_factor,
        robot_bearing_std=p.robot_bearing_std * bearing_factor,
        q_v0=p.q_v0 * process_factor,
        q_v1=p.q_v1 * process_factor,
        q_w0=p.q_w0 * process_factor,
        q_w1=p.q_w1 * process_factor,
    )


TUNING_GRID = tuple(
    (fr, fb, fq) for fr in (3.0, 6.0, 10.0) for fb in (2.0, 3.0, 4.0) for fq in (4.0, 8.0, 16.0)
)


def tune_inflation(
    dataset: MrclamDataset,
    params: NoiseParameters,
    t_start: float,
    t_end: float,
    grid: tuple[tuple[float, float, float], ...] = TUNING_GRID,
    min_coverage: float = 0.95,
) -> tuple[tuple[float, float, float], str]:
    """Choose noise inflation factors by replaying ``ekf_team`` over ``[t_start, t_end]``.

    Range errors of the MR.CLAM camera are strongly correlated from one
    image to the next (lag-1 correlation ~0.95), bearings less so (~0.6), and
    the odometry errors are correlated over seconds, so the white-noise
    statistics fitted above make a filter overconfident. Each candidate
    ``(range, bearing, process)`` factor triple of ``grid`` is replayed on the
    fitting window; the most accurate one whose 95 % ellipse covers the truth
    at least ``min_coverage`` of the time is returned (the best-covering one
    if none does), with a one-line summary.
    """
    offset = t_start - dataset.latest_odometry_start()
    if offset < 0:
        raise ValueError(f"t_start={t_start!r} is before the latest odometry start")
    scored = []
    for factors in grid:
        m = evaluate(
            replay(
                dataset,
                "ekf_team",
                scale_noise(params, *factors),
                t_end - t_start,
                start_offset=offset,
            )
        )
        scored.append((factors, m["mean_position_error_m"], m["nees_95_fraction"]))
    ok = [s for s in scored if s[2] >= min_coverage]
    best = min(ok, key=lambda s: s[1]) if ok else max(scored, key=lambda s: (s[2], -s[1]))
    summary = (
        f"mean position error {best[1]:.4f} m, 95% coverage {best[2]:.3f} "
        f"({len(ok)}/{len(scored)} candidates reached {min_coverage})"
    )
    return best[0], summary


def _replay_mle(
    dataset: MrclamDataset,
    params: NoiseParameters,
    tracks: list[OdometryTrack],
    init: np.ndarray,
    t0: float,
    grid: np.ndarray,
    stream: np.ndarray,
    progress: Callable[[float], None] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sliding-window pose-graph MLE (:class:`estimators.mle_online.TeamMLE`) on the stream.

    Landmarks enter the graph as extra, fixed "robots" that are observed with
    range and bearing; robots' first poses get the initial-pose prior.
    Odometry between events is fed in chunks of at most 0.25 s, each as an
    exact rotate-translate-rotate triple (the chunk's arc), with variances
    matching the fitted noise densities. Readings are gated (chi-square, 2
    DOF) against the current estimate and the last computed marginals. The
    sensor offset is not modelled here. Returns ``(estimate, cov, accepted,
    rejected)`` on ``grid``.
    """
    from estimators.mle_online import TeamMLE

    ids = dataset.robot_ids
    n_r = len(ids)
    lm_ids = sorted(dataset.landmarks)
    lm_index = {s: n_r + k for k, s in enumerate(lm_ids)}
    poses0 = np.vstack([init, [[*dataset.landmarks[s], 0.0] for s in lm_ids]])
    std0 = np.zeros((len(poses0), 3))
    std0[:n_r] = [params.initial_std_xy, params.initial_std_xy, params.initial_std_heading]
    mle = TeamMLE(
        len(poses0),
        initial_poses=poses0,
        initial_std=std0,
        anchor=None,
        motion_window=1.0,
        window=10,
        max_iterations=5,
    )
    fed = np.full(n_r, t0)
    tables = [tr.state(t0) for tr in tracks]
    noise = params.motion_noise

    def advance(i: int, t: float) -> None:
        while fed[i] < t - 1e-9:
            tb = min(t, fed[i] + 0.25)
            dt = tb - fed[i]
            cb = tracks[i].state(tb)
            delta, _ = OdometryTrack.motion(tables[i], cb, 0.0)
            dist = float(np.hypot(delta[0], delta[1]))
            phi1 = float(np.arctan2(delta[1], delta[0])) if dist > 1e-9 else 0.5 * delta[2]
            phi2 = float(delta[2]) - phi1
            qv = noise.v0 + noise.v1 * dist / dt
            qw = noise.w0 + noise.w1 * abs(delta[2]) / dt
            sw = float(np.sqrt(0.5 * qw * dt)) / (0.25 * dt)
            sv = float(np.sqrt(qv * dt)) / (0.5 * dt)
            mle.add_odometry(i, 0.0, phi1 / (0.25 * dt), 0.25 * dt, std=(0.0, sw))
            mle.add_odometry(i, dist / (0.5 * dt), 0.0, 0.5 * dt, std=(sv, 0.0))
            mle.add_odometry(i, 0.0, phi2 / (0.25 * dt), 0.25 * dt, std=(0.0, sw))
            tables[i] = cb
            fed[i] = tb

    gate = float(chi2.ppf(params.gate_prob, 2))
    bias = [params.for_robot(r)["bearing_bias_rad"] for r in ids]
    est = np.zeros((n_r, len(grid), 3))
    cov = np.zeros((n_r, len(grid), 3, 3))
    accepted = np.zeros(n_r, dtype=int)
    rejected = np.zeros(n_r, dtype=int)
    last_cov = np.tile(np.diag(std0[0] ** 2 + 1e-6), (len(poses0), 1, 1))
    last_cov[n_r:] = 0.0
    g = 0
    n_events = len(stream)
    report_every = max(1, n_events // 100)
    for e in range(n_events + 1):
        t = stream[e, 0] if e < n_events else np.inf
        while g < len(grid) and grid[g] <= t:
            for i in range(n_r):
                advance(i, grid[g])
            mle.step()
            est[:, g] = mle.poses()[:n_r]
            last_cov = mle.covariances()
            cov[:, g] = last_cov[:n_r]
            g += 1
        if e == n_events:
            break
        _, ri, subject, rng, bearing = stream[e]
        i, s = int(ri), int(subject)
        j = ids.index(s) if s in ids else lm_index[s]
        advance(i, t)
        if j < n_r:
            advance(j, t)
        robot_target = j < n_r
        r_cov = params.measurement_cov(rng, robot_target)
        z = np.array([rng - params.range_bias_m, wrap_angle(bearing - bias[i])])
        poses = mle.poses()
        d = poses[j, :2] - poses[i, :2]
        q = float(d @ d)
        if q < 1e-12:
            rejected[i] += 1
            continue
        pred = np.array([np.sqrt(q), np.arctan2(d[1], d[0]) - poses[i, 2]])
        nu = np.array([z[0] - pred[0], wrap_angle(z[1] - pred[1])])
        h_i = np.array([[-d[0], -d[1], 0.0] / pred[0], [d[1] / q, -d[0] / q, -1.0]])
        h_j = -h_i[:, :2]
        s_mat = h_i @ last_cov[i] @ h_i.T + h_j @ last_cov[j, :2, :2] @ h_j.T + r_cov
        if float(nu @ np.linalg.solve(s_mat, nu)) > gate:
            rejected[i] += 1
            continue
        mle.add_observation(i, j, z, np.sqrt(np.diag(r_cov)), components="rb")
        accepted[i] += 1
        if progress is not None and e % report_every == 0:
            progress(e / max(n_events, 1))
    return est, cov, accepted, rejected
