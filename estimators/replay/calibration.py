"""Calibration of the replay's noise model from a dataset's ground truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mrclam import MrclamDataset, interpolate_groundtruth
from estimators.replay.noise_model import NoiseParameters
from estimators.replay.runner import evaluate, replay

__all__ = ["TUNING_GRID", "fit_noise_parameters", "scale_noise", "tune_inflation"]


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
    motion, robot_scales = _fit_motion(dataset, t_start, t_end, per_robot)
    measurement, overrides = _fit_measurements(dataset, t_start, t_end, per_robot, robot_scales)
    base = NoiseParameters(**motion, **measurement, per_robot=overrides)
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


def _velocity_scales(win: np.ndarray) -> tuple[float, float]:
    """Least-squares scales of the commanded to the true speed and turn rate."""
    sv = win[:, 4] @ win[:, 0] / max(win[:, 0] @ win[:, 0], 1e-12)
    sw = win[:, 5] @ win[:, 1] / max(win[:, 1] @ win[:, 1], 1e-12)
    return float(sv), float(sw)


def _noise_density(res: np.ndarray) -> tuple[float, float]:
    """Non-negative fit ``q0 + q1 * |command|`` of squared residuals (rows ``|cmd|, res^2``)."""
    a = np.column_stack([np.ones(len(res)), res[:, 0]])
    from scipy.optimize import nnls

    coef, _ = nnls(a, res[:, 1])
    return float(coef[0]), float(coef[1])


def _fit_motion(
    dataset: MrclamDataset, t_start: float, t_end: float, per_robot: bool
) -> tuple[dict[str, float], dict[int, tuple[float, float] | None]]:
    """Odometry delay, velocity scales and noise densities (the :class:`NoiseParameters`
    fields), and each robot's velocity scales (``None`` with too little ground truth)."""
    ids = dataset.robot_ids
    lags = np.arange(0.0, 0.61, 0.02)
    costs = []
    for lag in lags:
        win = np.concatenate([_motion_windows(dataset, r, t_start, t_end, 1.0, lag) for r in ids])
        if len(win) < 10:
            raise ValueError(f"too little ground truth in [{t_start}, {t_end}] to fit motion")
        sw = win[:, 5] @ win[:, 1] / max(win[:, 1] @ win[:, 1], 1e-12)
        costs.append(np.mean((win[:, 5] - sw * win[:, 1]) ** 2))
    lag = float(lags[int(np.argmin(costs))])

    long_win = {r: _motion_windows(dataset, r, t_start, t_end, 4.0, lag) for r in ids}
    v_scale, w_scale = _velocity_scales(np.concatenate(list(long_win.values())))
    robot_scales = {
        r: _velocity_scales(long_win[r]) if len(long_win[r]) >= 10 else None for r in ids
    }
    res_v, res_w = [], []
    for r in ids:
        win = _motion_windows(dataset, r, t_start, t_end, 1.0, lag)
        sv, sw = robot_scales[r] if (per_robot and robot_scales[r]) else (v_scale, w_scale)
        res_v.append(np.column_stack([win[:, 2], (win[:, 4] - sv * win[:, 0]) ** 2 * 1.0]))
        res_w.append(np.column_stack([win[:, 3], (win[:, 5] - sw * win[:, 1]) ** 2 * 1.0]))
    q_v0, q_v1 = _noise_density(np.concatenate(res_v))
    q_w0, q_w1 = _noise_density(np.concatenate(res_w))
    fitted = {
        "odometry_delay_s": lag,
        "v_scale": v_scale,
        "w_scale": w_scale,
        "q_v0": q_v0,
        "q_v1": q_v1,
        "q_w0": q_w0,
        "q_w1": q_w1,
    }
    return fitted, robot_scales


def _fit_measurements(
    dataset: MrclamDataset,
    t_start: float,
    t_end: float,
    per_robot: bool,
    robot_scales: dict[int, tuple[float, float] | None],
) -> tuple[dict[str, float], dict[str, dict[str, float]]]:
    """Measurement delay, biases, sensor offset and noise (the :class:`NoiseParameters`
    fields), and the per-robot overrides (velocity scales, sensor offset, bearing bias)."""
    ids = dataset.robot_ids
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
    ranges = np.hypot(dx, dy)
    er = tab[:, 3] - range_bias - ranges
    eb = wrap_angle(tab[:, 4] - cal[:, 2] - np.arctan2(dy, dx))
    lm_sel = tab[:, 1] == 0
    rb_sel = tab[:, 1] == 1
    lm_noise = _range_bearing_noise(ranges[lm_sel], er[lm_sel], eb[lm_sel])
    rb_noise = (
        _range_bearing_noise(ranges[rb_sel], er[rb_sel], eb[rb_sel])
        if rb_sel.sum() >= 60
        else lm_noise
    )
    fitted = {
        "measurement_delay_s": delay,
        "range_bias_m": range_bias,
        "bearing_bias_rad": bb,
        "landmark_range_std_a": lm_noise[0],
        "landmark_range_std_b": lm_noise[1],
        "landmark_bearing_std": lm_noise[2],
        "robot_range_std_a": rb_noise[0],
        "robot_range_std_b": rb_noise[1],
        "robot_bearing_std": rb_noise[2],
        "sensor_x_m": sx,
        "sensor_y_m": sy,
    }
    return fitted, overrides


def _range_bearing_noise(
    ranges: np.ndarray, range_err: np.ndarray, bearing_err: np.ndarray
) -> tuple[float, float, float]:
    """Robust ``range_std = a + b * range`` (non-negative fit over six range bins, weighted
    by their counts) and bearing standard deviation; returns ``(a, b, bearing_std)``."""
    edges = np.quantile(ranges, np.linspace(0, 1, 7))
    mids, sds, ns = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        b = (ranges >= lo) & (ranges <= hi)
        if b.sum() >= 10:
            mids.append(np.median(ranges[b]))
            sds.append(_mad_std(range_err[b]))
            ns.append(b.sum())
    a_mat = np.column_stack([np.ones(len(mids)), mids]) * np.sqrt(ns)[:, None]
    from scipy.optimize import nnls

    coef, _ = nnls(a_mat, np.asarray(sds) * np.sqrt(ns))
    return float(coef[0]), float(coef[1]), _mad_std(bearing_err)


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
