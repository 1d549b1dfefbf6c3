"""Replay of a logged dataset through an estimator, and its evaluation against ground truth.

The protocol is described in :mod:`estimators.replay`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from estimators.gating import chi2_threshold
from estimators.geometry import wrap_angle
from estimators.mrclam import MrclamDataset, interpolate_groundtruth
from estimators.replay.landmark_screen import LandmarkScreen
from estimators.replay.noise_model import NoiseParameters
from estimators.team_ekf import MotionNoise, OdometryTrack, TeamEKF

__all__ = ["ESTIMATORS", "ReplayResult", "evaluate", "replay"]

ESTIMATORS = ("dead_reckoning", "ekf", "ekf_team", "mle")


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


def _check_replay_args(
    estimator: str, duration: float, grid_step: float, start_offset: float
) -> None:
    """Raise ``ValueError`` naming the first bad argument of :func:`replay`."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator {estimator!r}; choose one of {ESTIMATORS}")
    if not duration > 0:
        raise ValueError(f"duration must be > 0, got {duration!r}")
    if not grid_step > 0:
        raise ValueError(f"grid_step must be > 0, got {grid_step!r}")
    if not start_offset >= 0:
        raise ValueError(f"start_offset must be >= 0, got {start_offset!r}")


def _truth_on_grid(
    dataset: MrclamDataset, t0: float, t_end: float, grid: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground truth ``(R, T, 3)`` on ``grid``, its validity ``(R, T)`` and the poses at ``t0``.

    Raises ``ValueError`` when a robot has no ground truth at ``t0`` or the window has none.
    """
    ids = dataset.robot_ids
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
    return truth, valid, init


def _team_ekf(
    dataset: MrclamDataset, params: NoiseParameters, estimator: str, init: np.ndarray, t0: float
) -> TeamEKF:
    """The team EKF started at ``init`` (cooperative for ``ekf_team`` only)."""
    cov0 = np.diag([params.initial_std_xy**2] * 2 + [params.initial_std_heading**2])
    return TeamEKF(
        _build_tracks(dataset, params),
        init,
        cov0,
        t0,
        gate_prob=params.gate_prob,
        cooperative=estimator == "ekf_team",
        sensor_offset=[
            [params.for_robot(r)["sensor_x_m"], params.for_robot(r)["sensor_y_m"]]
            for r in dataset.robot_ids
        ],
    )


def _estimator_stream(
    dataset: MrclamDataset,
    params: NoiseParameters,
    estimator: str,
    t0: float,
    t_end: float,
    use_landmarks: bool,
) -> np.ndarray:
    """The measurements ``estimator`` uses in ``[t0, t_end]``: none for dead reckoning,
    landmarks only for ``ekf``, robot-to-robot only without ``use_landmarks``."""
    if estimator == "dead_reckoning":
        return np.zeros((0, 5))
    stream = _measurement_stream(dataset, params, t0, t_end)
    if not use_landmarks:
        stream = stream[~np.isin(stream[:, 2], list(dataset.landmarks))]
    if estimator == "ekf":
        stream = stream[np.isin(stream[:, 2], list(dataset.landmarks))]
    return stream


def replay(
    dataset: MrclamDataset,
    estimator: str,
    params: NoiseParameters,
    duration: float = 600.0,
    use_landmarks: bool = True,
    start_offset: float = 0.0,
    grid_step: float = 1.0,
    progress: Callable[[float], None] | None = None,
    screen_landmarks: bool = True,
) -> ReplayResult:
    """Run ``estimator`` on ``dataset`` with the standard protocol (see module doc).

    ``screen_landmarks``: the EKFs count the offset of a landmark that several robots
    find off the same way as map uncertainty
    (:class:`~estimators.replay.landmark_screen.LandmarkScreen`).

    ``start_offset`` shifts the start after the latest odometry start (to
    evaluate on other time spans); ``progress`` is called with the fraction
    of the run done. Raises ``ValueError`` for an unknown estimator or a
    non-positive duration, and when the window has no ground truth.
    """
    _check_replay_args(estimator, duration, grid_step, start_offset)
    wall = time.perf_counter()
    t0 = dataset.latest_odometry_start() + start_offset
    t_end = t0 + duration
    grid = t0 + grid_step * np.arange(1, int(np.floor(duration / grid_step + 1e-9)) + 1)
    truth, valid, init = _truth_on_grid(dataset, t0, t_end, grid)
    ekf = _team_ekf(dataset, params, estimator, init, t0)
    stream = _estimator_stream(dataset, params, estimator, t0, t_end, use_landmarks)
    if estimator == "mle":
        est, cov, accepted, rejected = _replay_mle(
            dataset, params, ekf.tracks, init, t0, grid, stream, progress
        )
    else:
        screen = LandmarkScreen() if screen_landmarks else None
        est, cov = _run_ekf(ekf, dataset, params, grid, stream, progress, screen)
        accepted, rejected = ekf.accepted.copy(), ekf.rejected.copy()
    if progress is not None:
        progress(1.0)
    runtime = time.perf_counter() - wall
    return ReplayResult(
        estimator=estimator,
        robot_ids=list(dataset.robot_ids),
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
    screen: LandmarkScreen | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Feed the time-sorted ``stream`` to ``ekf``; return the beliefs on ``grid``.
    With ``screen``, each landmark reading is kept there first and its noise inflated
    when the screen has flagged the landmark.

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
        t, ri, subject, range_, bearing = stream[e]
        while g < len(grid) and grid[g] <= t:
            record(g)
            g += 1
        i = int(ri)
        z = np.array([range_ - params.range_bias_m, wrap_angle(bearing - bearing_bias[i])])
        s = int(subject)
        if s in subj_index:
            ekf.update_robot(i, subj_index[s], z, params.measurement_cov(range_, True), t)
        else:
            r_cov = params.measurement_cov(range_, False)
            mark = dataset.landmarks[s]
            if screen is not None:
                ekf.predict_to(i, t)
                belief = ekf.belief(i)
                offset = ekf.sensor_offset[i]
                screen.add(s, i, t, belief.mean, belief.cov, offset, mark, z, r_cov)
                r_cov = screen.inflate(s, t, belief.mean, offset, mark, r_cov)
            ekf.update_landmark(i, mark, z, r_cov, t)
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
    feeder = _OdometryFeeder(mle, tracks, t0, params.motion_noise)
    gate = chi2_threshold(params.gate_prob, 2)
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
                feeder.advance(i, grid[g])
            mle.step()
            est[:, g] = mle.poses()[:n_r]
            last_cov = mle.covariances()
            cov[:, g] = last_cov[:n_r]
            g += 1
        if e == n_events:
            break
        _, ri, subject, range_, bearing = stream[e]
        i, s = int(ri), int(subject)
        j = ids.index(s) if s in ids else lm_index[s]
        feeder.advance(i, t)
        if j < n_r:
            feeder.advance(j, t)
        r_cov = params.measurement_cov(range_, j < n_r)
        z = np.array([range_ - params.range_bias_m, wrap_angle(bearing - bias[i])])
        if not _mle_gate(mle.poses(), last_cov, i, j, z, r_cov, gate):
            rejected[i] += 1
            continue
        mle.add_observation(i, j, z, np.sqrt(np.diag(r_cov)), components="rb")
        accepted[i] += 1
        if progress is not None and e % report_every == 0:
            progress(e / max(n_events, 1))
    return est, cov, accepted, rejected


class _OdometryFeeder:
    """Feeds each robot's odometry into a :class:`~estimators.mle_online.TeamMLE` up to a time.

    Chunks of at most 0.25 s, each as an exact rotate-translate-rotate triple
    with variances matching the noise densities ``noise``.
    """

    def __init__(self, mle, tracks: list[OdometryTrack], t0: float, noise: MotionNoise) -> None:
        self.mle = mle
        self.tracks = tracks
        self.noise = noise
        self.fed = np.full(len(tracks), t0)
        self.tables = [tr.state(t0) for tr in tracks]

    def advance(self, i: int, t: float) -> None:
        """Feed robot ``i``'s odometry up to time ``t``."""
        fed, tables, noise, mle = self.fed, self.tables, self.noise, self.mle
        while fed[i] < t - 1e-9:
            tb = min(t, fed[i] + 0.25)
            dt = tb - fed[i]
            cb = self.tracks[i].state(tb)
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


def _mle_gate(
    poses: np.ndarray,
    last_cov: np.ndarray,
    i: int,
    j: int,
    z: np.ndarray,
    r_cov: np.ndarray,
    gate: float,
) -> bool:
    """Whether the range-bearing reading ``z`` of node ``j`` from robot ``i`` passes the
    chi-square ``gate`` against ``poses`` and the marginals ``last_cov`` (False when the
    two positions coincide)."""
    d = poses[j, :2] - poses[i, :2]
    q = float(d @ d)
    if q < 1e-12:
        return False
    pred = np.array([np.sqrt(q), np.arctan2(d[1], d[0]) - poses[i, 2]])
    nu = np.array([z[0] - pred[0], wrap_angle(z[1] - pred[1])])
    h_i = np.array([[-d[0], -d[1], 0.0] / pred[0], [d[1] / q, -d[0] / q, -1.0]])
    h_j = -h_i[:, :2]
    s_mat = h_i @ last_cov[i] @ h_i.T + h_j @ last_cov[j, :2, :2] @ h_j.T + r_cov
    return not float(nu @ np.linalg.solve(s_mat, nu)) > gate
