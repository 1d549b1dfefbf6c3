"""MR.CLAM loader, team EKF and log replay, on a shipped excerpt of dataset 6."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from estimators.log_replay import (
    NoiseParameters,
    evaluate,
    fit_noise_parameters,
    load_noise_parameters,
    replay,
    save_noise_parameters,
    scale_noise,
)
from estimators.mrclam import interpolate_groundtruth, load_mrclam, read_table
from estimators.team_ekf import MotionNoise, OdometryTrack, TeamEKF

EXCERPT = Path(__file__).resolve().parents[1] / "data" / "mrclam_excerpt"
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def dataset():
    return load_mrclam(EXCERPT)


@pytest.fixture(scope="module")
def params():
    return load_noise_parameters()


@pytest.fixture()
def copy(tmp_path: Path) -> Path:
    dst = tmp_path / "ds"
    shutil.copytree(EXCERPT, dst)
    return dst


def _edit(path: Path, fn) -> None:
    lines = path.read_text().splitlines()
    path.write_text("\n".join(fn(lines)) + "\n")


# ---------------------------------------------------------------- loader


def test_loader_maps_barcodes_and_aligns_times(dataset) -> None:
    assert dataset.robot_ids == [1, 2, 3, 4, 5]
    assert len(dataset.landmarks) == 15 and set(dataset.landmarks) == set(range(6, 21))
    assert dataset.barcodes[5] == 1 and dataset.barcodes[23] == 5 and dataset.barcodes[63] == 6
    # times are relative to the first time stamp of any robot file
    assert min(log.groundtruth[0, 0] for log in dataset.robots.values()) == 0.0
    # the excerpt starts 10 s into dataset 6, whose latest odometry start is at ~15.9 s
    assert dataset.time_origin == pytest.approx(1248444185.133)
    assert dataset.latest_odometry_start() + dataset.time_origin == pytest.approx(1248444191.043)
    for rid, log in dataset.robots.items():
        subjects = set(log.measurements[:, 1].astype(int))
        assert subjects <= set(range(1, 21)) - {rid}
        assert np.all(np.diff(log.odometry[:, 0]) >= 0)
    # robot 2 sees subject 15 (barcode 90) as the first reading of its log excerpt
    first = dataset.robots[2].measurements[0]
    assert first[1] == 15 and first[2] == pytest.approx(2.737)


def test_unknown_barcode_is_skipped_and_counted(copy: Path, dataset) -> None:
    f = copy / "Robot3_Measurement.dat"
    _edit(f, lambda ls: ls[:10] + [ls[10].split()[0] + " 43 2.0 0.1"] + ls[10:])
    _edit(f, lambda ls: ls + [ls[-1].split()[0] + " 43 2.5 0.2", ls[-1].split()[0] + " 99 1 0"])
    ds = load_mrclam(copy)
    assert ds.unknown_barcodes == {43: 2, 99: 1}
    assert len(ds.robots[3].measurements) == len(dataset.robots[3].measurements)


def test_truncated_line_names_file_and_line(copy: Path) -> None:
    f = copy / "Robot2_Odometry.dat"
    _edit(f, lambda ls: ls[:20] + [" ".join(ls[20].split()[:2])] + ls[21:])
    with pytest.raises(ValueError, match=r"Robot2_Odometry\.dat:21: expected 3 columns, got 2"):
        load_mrclam(copy)


def test_malformed_value_names_file_and_line(copy: Path) -> None:
    f = copy / "Robot5_Groundtruth.dat"
    _edit(f, lambda ls: ls[:7] + [ls[7].replace(ls[7].split()[2], "1.2.3")] + ls[8:])
    with pytest.raises(ValueError, match=r"Robot5_Groundtruth\.dat:8: not a number"):
        load_mrclam(copy)


def test_non_monotonic_time_names_file_and_line(copy: Path) -> None:
    f = copy / "Robot1_Measurement.dat"
    _edit(f, lambda ls: ls[:30] + [ls[31], ls[30]] + ls[32:] if ls[30] != ls[31] else ls)
    lines = f.read_text().splitlines()
    assert float(lines[30].split()[0]) > float(lines[31].split()[0])
    with pytest.raises(ValueError, match=r"Robot1_Measurement\.dat:32: non-monotonic time"):
        load_mrclam(copy)


def test_missing_file_raises_file_not_found(copy: Path) -> None:
    (copy / "Robot4_Odometry.dat").unlink()
    with pytest.raises(FileNotFoundError, match="Robot4_Odometry.dat"):
        load_mrclam(copy)
    (copy / "Landmark_Groundtruth.dat").unlink()
    with pytest.raises(FileNotFoundError, match="Landmark_Groundtruth.dat"):
        load_mrclam(copy)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_mrclam(copy / "nowhere")


def test_empty_file_is_an_error(tmp_path: Path) -> None:
    f = tmp_path / "Robot1_Odometry.dat"
    f.write_text("# header only\n")
    with pytest.raises(ValueError, match="no data lines"):
        read_table(f, 3)


def test_interpolate_groundtruth_skips_gaps_and_unwraps_heading() -> None:
    gt = np.array(
        [[0.0, 0.0, 0.0, 3.1], [0.1, 1.0, 0.0, -3.1], [0.2, 2.0, 0.0, -3.0], [5.0, 3.0, 0.0, 0.0]]
    )
    pose, ok = interpolate_groundtruth(gt, np.array([-1.0, 0.05, 0.15, 1.0, 5.0, 6.0]))
    assert ok.tolist() == [False, True, True, False, True, False]
    assert pose[1, 0] == pytest.approx(0.5)
    # halfway between 3.1 and -3.1 through pi, not through 0
    assert abs(pose[1, 2]) == pytest.approx(np.pi, abs=1e-9)
    assert np.isnan(pose[3]).all()


# ---------------------------------------------------------------- motion model


def _track(seed: int = 0, n: int = 400) -> OdometryTrack:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.005, 0.03, n))
    v = rng.uniform(0.0, 0.1, n)
    w = rng.uniform(-0.5, 0.5, n)
    return OdometryTrack(t, v, w, MotionNoise(1e-4, 1e-3, 2e-4, 5e-3), delay=0.1)


def test_odometry_track_matches_step_by_step_integration() -> None:
    tr = _track()
    pose = np.array([1.0, -2.0, 0.7])
    t_a, t_b = tr.times[10] + 0.004, tr.times[300] + 0.002
    delta, _ = OdometryTrack.motion(tr.state(t_a), tr.state(t_b), pose[2])
    # brute force: tiny Euler steps through the piecewise-constant commands
    inner = tr.times[(tr.times > t_a) & (tr.times < t_b)]
    ts = np.union1d(np.linspace(t_a, t_b, 200001), inner)  # steps never straddle a record
    k = np.searchsorted(tr.times, ts[:-1], side="right") - 1
    dt = np.diff(ts)
    th = pose[2] + np.concatenate([[0.0], np.cumsum(tr._w[k] * dt)])[:-1]
    x = pose[0] + np.sum(tr._v[k] * dt * np.cos(th))
    y = pose[1] + np.sum(tr._v[k] * dt * np.sin(th))
    assert delta[0] + pose[0] == pytest.approx(x, abs=1e-6)
    assert delta[1] + pose[1] == pytest.approx(y, abs=1e-6)
    assert delta[2] == pytest.approx(np.sum(tr._w[k] * dt), abs=1e-9)


def test_odometry_track_composes_exactly() -> None:
    tr = _track(1)
    ta, tb, tc = tr.times[5] + 0.001, tr.times[150] + 0.007, tr.times[390]
    phi = 0.3
    d_ac, q_ac = OdometryTrack.motion(tr.state(ta), tr.state(tc), phi)
    d_ab, q_ab = OdometryTrack.motion(tr.state(ta), tr.state(tb), phi)
    d_bc, q_bc = OdometryTrack.motion(tr.state(tb), tr.state(tc), phi + d_ab[2])
    f = np.array([[1, 0, -d_bc[1]], [0, 1, d_bc[0]], [0, 0, 1.0]])
    np.testing.assert_allclose(d_ab + d_bc, d_ac, atol=1e-12)
    np.testing.assert_allclose(f @ q_ab @ f.T + q_bc, q_ac, rtol=1e-8, atol=1e-14)
    assert np.all(np.linalg.eigvalsh(q_ac) > 0)


def test_odometry_track_covariance_matches_monte_carlo() -> None:
    rng = np.random.default_rng(3)
    n = 200
    t = np.arange(n) * 0.02
    v = np.full(n, 0.08)
    w = np.full(n, 0.3)
    noise = MotionNoise(2e-4, 0.0, 1e-3, 0.0)
    tr = OdometryTrack(t, v, w, noise)
    _, q = OdometryTrack.motion(tr.state(0.0), tr.state(t[-1]), 0.0)
    # simulate white velocity noise with the same densities
    m = 4000
    dt = 0.02
    nv = rng.normal(0, np.sqrt(noise.v0 / dt), (m, n - 1))
    nw = rng.normal(0, np.sqrt(noise.w0 / dt), (m, n - 1))
    th = np.concatenate([np.zeros((m, 1)), np.cumsum((w[0] + nw) * dt, axis=1)], axis=1)
    x = np.sum((v[0] + nv) * dt * np.cos(th[:, :-1]), axis=1)
    y = np.sum((v[0] + nv) * dt * np.sin(th[:, :-1]), axis=1)
    emp = np.cov(np.stack([x, y, th[:, -1]]))
    np.testing.assert_allclose(np.diag(emp), np.diag(q), rtol=0.12)


def test_odometry_track_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="backwards"):
        OdometryTrack(np.array([0.0, 1.0, 0.5]), np.zeros(3), np.zeros(3), MotionNoise(0, 0, 0, 0))
    with pytest.raises(ValueError, match="NaN"):
        OdometryTrack(
            np.array([0.0, 1.0]), np.array([0.0, np.nan]), np.zeros(2), MotionNoise(0, 0, 0, 0)
        )
    with pytest.raises(ValueError, match="w0"):
        MotionNoise(0.0, 0.0, -1.0, 0.0)


# ---------------------------------------------------------------- team EKF


def _still_tracks(n: int) -> list[OdometryTrack]:
    return [
        OdometryTrack(np.array([0.0]), np.zeros(1), np.zeros(1), MotionNoise(1e-4, 0, 1e-4, 0))
        for _ in range(n)
    ]


def test_team_ekf_gate_rejects_outlier_and_counts_it() -> None:
    ekf = TeamEKF(_still_tracks(2), np.array([[0.0, 0, 0], [2.0, 0, 0]]), np.eye(3) * 1e-4, 0.0)
    r = np.diag([0.05**2, 0.01**2])
    lm = np.array([3.0, 0.0])
    assert ekf.update_landmark(0, lm, np.array([3.02, 0.005]), r, t=1.0)
    x_before = ekf.x.copy()
    assert not ekf.update_landmark(0, lm, np.array([3.0, 0.8]), r, t=1.1)
    np.testing.assert_array_equal(ekf.x, x_before)
    assert ekf.rejected.tolist() == [1, 0] and ekf.accepted.tolist() == [1, 0]


def test_team_ekf_robot_update_correlates_and_informs_the_other_robot() -> None:
    cov = np.array([np.diag([1e-4, 1e-4, 1e-4]), np.diag([0.25, 0.25, 0.01])])
    truth = np.array([[0.0, 0.0, 0.0], [2.0, 1.0, 0.5]])
    start = truth + np.array([[0, 0, 0], [0.3, -0.2, 0.0]])
    ekf = TeamEKF(_still_tracks(2), start, cov, 0.0)
    independent = TeamEKF(_still_tracks(2), start, cov, 0.0, cooperative=False)
    d = truth[1, :2] - truth[0, :2]
    z = np.array([np.hypot(*d), np.arctan2(d[1], d[0])])
    r = np.diag([0.02**2, 0.005**2])
    assert ekf.update_robot(0, 1, z, r, t=0.5)
    assert not independent.update_robot(0, 1, z, r, t=0.5)
    assert np.linalg.norm(ekf.x[3:5] - truth[1, :2]) < 0.05
    assert np.abs(ekf.P[0:3, 3:6]).max() > 0  # cross-covariance created
    np.testing.assert_array_equal(independent.P[0:3, 3:6], 0.0)
    np.testing.assert_allclose(ekf.P, ekf.P.T)
    assert np.all(np.linalg.eigvalsh(ekf.P) > 0)
    with pytest.raises(ValueError, match="itself"):
        ekf.update_robot(1, 1, z, r)


def test_team_ekf_sensor_offset_changes_prediction() -> None:
    lm = np.array([3.0, 0.0])
    r = np.diag([0.05**2, 0.01**2])
    plain = TeamEKF(_still_tracks(1), np.zeros((1, 3)), np.eye(3) * 0.1, 0.0)
    shifted = TeamEKF(
        _still_tracks(1), np.zeros((1, 3)), np.eye(3) * 0.1, 0.0, sensor_offset=[[0.5, 0.0]]
    )
    z = np.array([2.5, 0.0])  # exactly what a sensor 0.5 m ahead reads
    assert plain.update_landmark(0, lm, z, r)
    assert shifted.update_landmark(0, lm, z, r)
    assert np.linalg.norm(shifted.x[:2]) < 0.01
    assert plain.x[0] > 0.3


# ---------------------------------------------------------------- replay


def test_ekf_team_beats_dead_reckoning_on_excerpt(dataset, params) -> None:
    metrics = {
        est: evaluate(replay(dataset, est, params, duration=100.0))
        for est in ("dead_reckoning", "ekf", "ekf_team")
    }
    dr, ekf, team = metrics["dead_reckoning"], metrics["ekf"], metrics["ekf_team"]
    # Bands from the same 100 s replay of the full dataset 6 at start offsets 0, 100, ..
    # 700 s (8 windows; offset 0 is this excerpt's window): each is the worst window's
    # figure plus one sd over the windows. This excerpt: team error 0.061 m, team / dead
    # reckoning 0.15, EKF / dead reckoning 0.27, NEES fraction 0.97.
    assert dr["position_rmse_m"] > 0.2  # windows 0.23-0.82 m
    # team error: windows 0.040-0.088 m, sd 0.017
    assert team["mean_position_error_m"] < 0.105
    # team / dead reckoning: windows 0.11-0.23, sd 0.044
    assert team["mean_position_error_m"] < 0.27 * dr["mean_position_error_m"]
    assert team["position_rmse_m"] < dr["position_rmse_m"]
    # EKF alone / dead reckoning: windows 0.16-0.42, sd 0.084
    assert ekf["mean_position_error_m"] < 0.5 * dr["mean_position_error_m"]
    # NEES 95 % fraction: windows 0.946-1.0, sd 0.020
    assert team["nees_95_fraction"] > 0.92
    assert dr["rejected_measurements"] == 0
    assert team["accepted_measurements"] > ekf["accepted_measurements"] > 1000
    assert all(r["evaluated_times"] == 100 for r in team["per_robot"])


def test_mle_runs_on_excerpt_and_beats_dead_reckoning(dataset, params, tmp_path: Path) -> None:
    # through the CLI in a subprocess: it pins BLAS to one thread before numpy loads, which
    # keeps the pose-graph solver fast on a shared machine
    out = tmp_path / "mle.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [
        sys.executable,
        str(ROOT / "scripts" / "replay_logs.py"),
        str(EXCERPT),
        "--estimator",
        "mle",
        "--duration",
        "15",
        "--json",
        str(out),
        "--no-progress",
    ]
    subprocess.run(cmd, check=True, env=env, capture_output=True, timeout=120)
    mle = json.loads(out.read_text())
    dr = evaluate(replay(dataset, "dead_reckoning", params, duration=15.0))
    assert mle["estimator"] == "mle"
    assert mle["accepted_measurements"] > 100
    assert mle["mean_position_error_m"] < 0.1
    assert mle["final_position_error_m"] < dr["final_position_error_m"]


def test_no_landmarks_uses_only_robot_measurements(dataset, params) -> None:
    res = replay(dataset, "ekf_team", params, duration=60.0, use_landmarks=False)
    m = evaluate(res)
    robot_readings = sum(
        int(np.sum(np.isin(log.measurements[:, 1], dataset.robot_ids)))
        for log in dataset.robots.values()
    )
    assert 0 < m["accepted_measurements"] + m["rejected_measurements"] <= robot_readings
    assert m["use_landmarks"] is False


def test_replay_rejects_bad_arguments(dataset, params) -> None:
    with pytest.raises(ValueError, match="unknown estimator 'kalman'"):
        replay(dataset, "kalman", params)
    with pytest.raises(ValueError, match="duration"):
        replay(dataset, "ekf", params, duration=-1.0)
    with pytest.raises(ValueError, match="no ground truth"):
        replay(dataset, "ekf", params, duration=10.0, start_offset=500.0)


def test_fit_on_excerpt_gives_plausible_parameters(dataset, tmp_path: Path) -> None:
    p = fit_noise_parameters(dataset, tune=False)
    assert 0.0 <= p.odometry_delay_s <= 0.6
    assert 0.7 < p.v_scale < 1.1 and 0.7 < p.w_scale < 1.1
    assert 0.001 < p.landmark_bearing_std < 0.05
    assert 0.0 <= p.measurement_delay_s < 0.2
    assert set(p.per_robot) == {"1", "2", "3", "4", "5"}
    save_noise_parameters(p, tmp_path / "p.json")
    assert load_noise_parameters(tmp_path / "p.json") == p
    # the fitted-and-inflated model works on the replay
    m = evaluate(replay(dataset, "ekf_team", scale_noise(p, 6.0, 3.0, 8.0), duration=100.0))
    assert m["mean_position_error_m"] < 0.15


def test_noise_parameter_file_validation(tmp_path: Path) -> None:
    f = tmp_path / "bad.json"
    f.write_text(json.dumps({"q_v0": 1e-4, "bogus": 1}))
    with pytest.raises(ValueError, match="bogus"):
        load_noise_parameters(f)
    with pytest.raises(ValueError, match="gate_prob"):
        NoiseParameters(gate_prob=1.5)
    with pytest.raises(ValueError, match="per_robot"):
        NoiseParameters(per_robot={"1": {"warp": 1.0}})
    with pytest.raises(FileNotFoundError):
        load_noise_parameters(tmp_path / "none.json")


def test_cli_writes_the_documented_json(tmp_path: Path, script_module) -> None:
    replay_logs = script_module("replay_logs")
    out = tmp_path / "m.json"
    png = tmp_path / "m.png"
    rc = replay_logs.main(
        [
            str(EXCERPT),
            "--estimator",
            "ekf_team",
            "--duration",
            "30",
            "--json",
            str(out),
            "--plot",
            str(png),
            "--no-progress",
        ]
    )
    assert rc == 0 and png.stat().st_size > 10_000
    m = json.loads(out.read_text())
    for key in (
        "mean_position_error_m",
        "position_rmse_m",
        "mean_heading_error_deg",
        "nees_95_fraction",
        "per_robot",
        "rejected_measurements",
        "runtime_s",
    ):
        assert key in m
    assert len(m["per_robot"]) == 5
    assert {"final_position_error_m", "nees_95_fraction"} <= set(m["per_robot"][0])


def test_cli_fit_writes_a_parameter_file_the_replay_reads(tmp_path: Path, script_module) -> None:
    replay_logs = script_module("replay_logs")
    pfile = tmp_path / "fit.json"
    args = [str(EXCERPT), "--fit", "--fit-start", "0", "--fit-end", "60", "--no-tune"]
    assert replay_logs.main(args + ["--params", str(pfile)]) == 0
    fitted = load_noise_parameters(pfile)
    assert "t=[" in fitted.fitted_on and "not tuned" in fitted.fitted_on
    assert replay_logs.main(args) == 2  # --fit without --params
    out = tmp_path / "m.json"
    rc = replay_logs.main(
        [
            str(EXCERPT),
            "--estimator",
            "ekf",
            "--duration",
            "20",
            "--start-offset",
            "60",
            "--params",
            str(pfile),
            "--json",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    m = json.loads(out.read_text())
    assert m["params"] == str(pfile) and m["start_offset_s"] == 60.0
    assert all(r["evaluated_times"] == 20 for r in m["per_robot"])


def _screen_readings(screen, robot: int, pose: np.ndarray, landmark: np.ndarray,
                     mark: np.ndarray, rng: np.random.Generator, t0: float) -> None:
    """Five readings of the landmark truly at ``landmark`` (the map says ``mark``) from
    robot ``robot`` believed, rightly, at ``pose``."""
    r = np.diag([0.05**2, 0.01**2])
    for k in range(5):
        d = landmark - pose[:2]
        z = np.array([np.hypot(*d), np.arctan2(d[1], d[0]) - pose[2]])
        z = z + rng.normal(0.0, [0.05, 0.01])
        screen.add(7, robot, t0 + 0.2 * k, pose, np.eye(3) * 1e-4, np.zeros(2), mark, z, r)


def test_landmark_screen_flags_a_landmark_that_two_robots_find_off_the_same_way() -> None:
    from estimators.replay.landmark_screen import LandmarkScreen

    rng = np.random.default_rng(0)
    truth, mark = np.array([2.0, 1.0]), np.array([2.3, 1.2])  # the map is 0.36 m off
    screen = LandmarkScreen()
    _screen_readings(screen, 0, np.array([0.0, 0.0, 0.3]), truth, mark, rng, 0.0)
    assert screen.offset(7, 1.0) is None  # one robot: it may be the robot that is off
    r = np.diag([0.05**2, 0.01**2])
    assert np.array_equal(screen.inflate(7, 1.0, np.zeros(3), np.zeros(2), mark, r), r)
    _screen_readings(screen, 1, np.array([4.0, 3.0, -2.0]), truth, mark, rng, 1.0)
    off = screen.offset(7, 2.0)
    assert off is not None and np.linalg.norm(off - (truth - mark)) < 0.05
    # Seen from where the line of sight is across the offset, the bearing widens, the
    # range hardly.
    side = mark + 3.0 * np.array([-off[1], off[0]]) / np.linalg.norm(off)
    wide = screen.inflate(7, 2.0, np.array([*side, 0.0]), np.zeros(2), mark, r)
    assert wide[1, 1] > 10 * r[1, 1] and wide[0, 0] < 1.5 * r[0, 0]
    # A third robot's own error (offset the other way) breaks the agreement.
    _screen_readings(screen, 2, np.array([0.0, 3.0, 0.0]), truth + 2 * (mark - truth), mark,
                     rng, 1.5)
    assert screen.offset(7, 2.5) is None
    assert screen.offset(7, 40.0) is None  # forgotten after window_s


def test_landmark_screen_checks_its_arguments() -> None:
    from estimators.replay.landmark_screen import LandmarkScreen

    for kwargs, match in (({"window_s": 0.0}, "window_s"), ({"min_robots": 1}, "min_robots"),
                          ({"min_offset_m": -1.0}, "min_offset_m"),
                          ({"min_readings": 0}, "min_readings"), ({"prob": 1.0}, "probability")):
        with pytest.raises(ValueError, match=match):
            LandmarkScreen(**kwargs)


def test_a_landmark_misplaced_in_the_map_costs_less_with_the_screen(dataset, params) -> None:
    """Landmark 19 put 0.4 m off in the map: the robots that read it agree on where it is,
    and counting that offset as map uncertainty keeps it from pulling them."""
    import dataclasses

    marks = dict(dataset.landmarks)
    marks[19] = marks[19] + 0.4 / np.sqrt(2.0)
    biased = dataclasses.replace(dataset, landmarks=marks)
    for est, bound in (("ekf_team", 0.072), ("ekf", 0.135)):
        on = evaluate(replay(biased, est, params, duration=100.0))
        off = evaluate(replay(biased, est, params, duration=100.0, screen_landmarks=False))
        assert on["mean_position_error_m"] < bound < off["mean_position_error_m"], est
    clean_on = evaluate(replay(dataset, "ekf_team", params, duration=100.0))
    clean_off = evaluate(replay(dataset, "ekf_team", params, duration=100.0,
                                screen_landmarks=False))
    assert clean_on["mean_position_error_m"] < 1.02 * clean_off["mean_position_error_m"]
