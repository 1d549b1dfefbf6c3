"""The team EKF's landmark lock-out recovery: it re-localizes a lost robot and leaves an
accurate filter alone when a landmark is biased or misidentified or the robot turns."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from estimators.gating import chi2_threshold
from estimators.relocalization import Relocalizer, fit_pose
from estimators.team_ekf import MotionNoise, OdometryTrack, TeamEKF

EXCERPT = Path(__file__).resolve().parents[1] / "data" / "mrclam_excerpt"
NEES_BOUND = chi2_threshold(0.999, 3)
R = np.diag([0.05**2, 0.01**2])
NOISE = MotionNoise(1e-4, 0.0, 1e-4, 0.0)
# Landmarks: A ahead, B and C to the left and right, E far behind (all > 1 m apart).
A, B, C, E = (np.array(p) for p in ((4.0, 0.0), (3.0, 3.0), (3.0, -3.0), (-5.0, 1.0)))


def _reading(pose: np.ndarray, mark: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    d = mark - pose[:2]
    z = np.array([np.hypot(*d), math.atan2(d[1], d[0]) - pose[2]])
    return z + rng.normal(0.0, np.sqrt(np.diag(R)))


def _still(mean=(0.0, 0.0, 0.0), var: float = 1e-3, **kw) -> TeamEKF:
    track = OdometryTrack(np.array([0.0]), np.zeros(1), np.zeros(1), NOISE)
    return TeamEKF([track], np.array([mean]), np.eye(3) * var, 0.0, **kw)


def _error(ekf: TeamEKF, truth: np.ndarray) -> tuple[float, float]:
    d = ekf.x[:3] - truth
    return float(np.hypot(d[0], d[1])), abs(math.remainder(d[2], 2 * math.pi))


def test_a_biased_landmark_read_in_bursts_does_not_move_an_accurate_filter():
    """Bursts of three and more readings of a landmark the map puts 0.5 m off, between
    good readings of two others: one landmark's readings agree with each other however
    wrong it is, so they are no proof that the filter is lost."""
    rng = np.random.default_rng(0)
    ekf = _still()
    truth = np.zeros(3)
    biased = A + np.array([0.0, 0.5])
    t = 0.0
    for burst in range(8):
        for _ in range(4):
            t += 0.1
            assert not ekf.update_landmark(0, biased, _reading(truth, A, rng), R, t=t)
        t += 0.1
        good = (B, C)[burst % 2]
        assert ekf.update_landmark(0, good, _reading(truth, good, rng), R, t=t)
    pos, head = _error(ekf, truth)
    assert pos < 0.03 and head < 0.01
    assert np.trace(ekf.P[:2, :2]) < 2e-3  # not widened
    assert ekf.relocalizer.recoveries == 0


def test_a_biased_and_a_misidentified_landmark_together_do_not_agree_on_a_pose():
    """Two landmarks whose readings the gate mostly rejects (A biased, B's barcode read
    as E's), but the well-read C and the rest disagree with every single pose."""
    rng = np.random.default_rng(1)
    ekf = _still()
    truth = np.zeros(3)
    biased = A + np.array([0.0, 0.5])
    t = 0.0
    for k in range(40):
        t += 0.1
        kind = k % 4
        if kind == 3:
            assert ekf.update_landmark(0, C, _reading(truth, C, rng), R, t=t)
        else:
            mark, seen = (biased, A) if kind == 0 else (E, B)
            assert not ekf.update_landmark(0, mark, _reading(truth, seen, rng), R, t=t)
    pos, head = _error(ekf, truth)
    assert pos < 0.03 and head < 0.01
    assert ekf.relocalizer.recoveries == 0


def test_bursts_while_turning_are_no_evidence():
    """Bearings stamped 0.3 s late while the robot turns at 0.5 rad/s are off by 0.15 rad
    for every landmark alike, as if the heading were wrong; the filter keeps its belief."""
    rng = np.random.default_rng(2)
    w = 0.5
    track = OdometryTrack(np.array([0.0]), np.zeros(1), np.array([w]), NOISE)
    ekf = TeamEKF([track], np.zeros((1, 3)), np.eye(3) * 1e-3, 0.0)
    for k in range(1, 31):
        t = 0.1 * k
        truth = np.array([0.0, 0.0, w * t])
        mark = (A, B, C)[k % 3]
        z = _reading(truth, mark, rng)
        z[1] += w * 0.3
        ekf.update_landmark(0, mark, z, R, t=t)
    pos, head = _error(ekf, np.array([0.0, 0.0, w * 3.0]))
    assert pos < 0.05 and head < 0.05
    assert ekf.relocalizer.recoveries == 0


def test_a_lost_robot_driving_among_three_landmarks_is_relocalized():
    """Believed 2 m and 0.3 rad away within a few centimetres while it drives at 0.2 m/s:
    readings of three landmarks in turn, related by the odometry, re-localize it within
    a second, and the belief covers its error; recover_after=None never recovers."""
    v = 0.2
    track = OdometryTrack(np.array([0.0]), np.array([v]), np.zeros(1), NOISE)
    for recover_after, found in ((3, True), (None, False)):
        rng = np.random.default_rng(3)
        ekf = TeamEKF([track], np.array([[1.5, -1.3, 0.3]]), np.eye(3) * 1e-3, 0.0,
                      recover_after=recover_after)
        accepted = []
        for k in range(1, 31):
            t = 0.1 * k
            truth = np.array([v * t, 0.0, 0.0])
            mark = (A, B, C)[k % 3]
            accepted.append(ekf.update_landmark(0, mark, _reading(truth, mark, rng), R, t=t))
        pos, head = _error(ekf, truth)
        assert (pos < 0.1 and head < 0.03) == found
        if found:
            assert ekf.relocalizer.recoveries == 1
            assert accepted.index(True) < 10 and all(accepted[10:])
            d = ekf.x[:3] - truth
            assert d @ np.linalg.solve(ekf.P, d) < NEES_BOUND


def test_fit_pose_recovers_a_pose_from_readings_along_a_path():
    rng = np.random.default_rng(4)
    pose = np.array([1.0, -0.5, 2.0])
    # Earlier poses relative to the last one: the robot came 0.5 m straight back.
    rel = np.array([[-0.1 * k, 0.0, 0.0] for k in range(5, 0, -1)] * 2)
    marks = np.array([A, B, C, E, A, B, C, E, A, B])
    z = np.empty((len(rel), 2))
    for k, (dr, mark) in enumerate(zip(rel, marks, strict=True)):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        at = np.array([pose[0] + c * dr[0], pose[1] + s * dr[0], pose[2]])
        z[k] = _reading(at, mark, rng)
    r = np.repeat(R[None], len(rel), axis=0)
    q = np.zeros((len(rel), 3, 3))
    fitted, cov, chi = fit_pose(rel, marks, z, r, q, np.zeros(2))
    d = fitted - pose
    assert d @ np.linalg.solve(cov, d) < NEES_BOUND
    assert chi < chi2_threshold(0.999, 2 * len(rel) - 3)
    # One reading leaves the pose undetermined.
    assert fit_pose(rel[:1], marks[:1], z[:1], r[:1], q[:1], np.zeros(2)) is None


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [({"min_readings": 0}, "min_readings"), ({"min_landmarks": 1}, "min_landmarks"),
     ({"window_s": 0.0}, "window_s"), ({"max_turn_rate": math.nan}, "max_turn_rate"),
     ({"min_baseline": -1.0}, "min_baseline"), ({"max_std": (1.0, 0.0)}, "max_std"),
     ({"agree_prob": 1.0}, "probability"), ({"suspect_prob": 0.0}, "probability"),
     ({"min_jump": 0.0}, "min_jump"), ({"consensus_std": (1.0,)}, "consensus_std"),
     ({"min_places": 1}, "min_places"), ({"min_ratio": 0.5}, "min_ratio")],
)
def test_relocalizer_checks_its_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Relocalizer(1, OdometryTrack.motion, **kwargs)


# ------------------------------------------------------------------ real logs
@pytest.fixture(scope="module")
def excerpt():
    from estimators.mrclam import load_mrclam
    from estimators.replay import load_noise_parameters

    return load_mrclam(EXCERPT), load_noise_parameters()


def test_kidnapped_robot_on_mrclam_converges_within_20_s_of_its_first_landmark(
    excerpt, script_module
):
    """Robot 1, or 5, starts 3.6 m from its true pose with the usual 1 cm covariance.
    Robot 1 is locked out (its readings fail the gate); robot 5's readings soon pass it,
    narrowly, on a wrong pose that the filter would leave only slowly."""
    stress = script_module("bench/recovery_stress")
    data, params = excerpt
    for robot in (1, 5):
        for est in ("ekf", "ekf_team"):
            out = stress.run_case(data, est, params, 0.0, 100.0, kidnap=robot)
            assert out["seconds_to_0.5m_after_first_landmark"] <= 20.0, (robot, est, out)
            assert out["recoveries"] >= 1


def test_a_misidentified_landmark_on_mrclam_costs_little(excerpt, script_module):
    """Every reading of landmark 13 labelled as landmark 16 (metres away)."""
    stress = script_module("bench/recovery_stress")
    data, params = excerpt
    clean = stress.run_case(data, "ekf_team", params, 0.0, 100.0)
    bad = stress.run_case(stress.misidentified(data, 13), "ekf_team", params, 0.0, 100.0)
    assert bad["mean_position_error_m"] < 1.1 * clean["mean_position_error_m"]
    assert bad["recoveries"] == 0
    for mean, rmse, _ in bad["per_robot"].values():
        assert rmse < 2.0 * mean


def test_a_biased_landmark_under_an_overconfident_model_does_not_trigger_a_recovery(
    excerpt, script_module
):
    """Landmark 16 put 0.4 m off in the map and every noise figure halved (a model twice too
    confident, as on a dataset noisier than the one it was fitted on): an accurate filter's
    readings of good landmarks sit near their gate, those of the biased one fail it, and
    none of that proves the robot lost. The filter must do as well as with no recovery."""
    from estimators.replay import scale_noise

    stress = script_module("bench/recovery_stress")
    data, params = excerpt
    biased = stress.biased_landmark(data, 16, 0.4)
    tight = scale_noise(params, 0.5, 0.5, 0.25)
    out = stress.run_case(biased, "ekf_team", tight, 0.0, 100.0)
    assert out["recoveries"] == 0
    mean, rmse, _ = out["per_robot"][5]
    assert mean < 0.12 and rmse < 2.0 * mean


def test_recovery_stress_script_refuses_bad_input(script_main, tmp_path, capsys):
    main = script_main("bench/recovery_stress")
    assert main([str(tmp_path / "missing")]) == 2
    assert "dataset" in capsys.readouterr().err
    for bad in (["--windows", "0-300"], ["--windows", "0:0"], ["--landmarks", "99"],
                ["--cases", "kidnapped", "--kidnap", "9"], ["--noise-scale", "0"]):
        assert main([str(EXCERPT), *bad]) == 2
        assert capsys.readouterr().err.count("\n") == 1


def test_recovery_table_groups_cases_and_compares_trees(script_module, script_main, tmp_path):
    table = script_module("bench/recovery_table")
    robots = {"1": [0.05, 0.06, 0], "2": [0.1, 0.3, 4]}
    before = {
        "0:300 biased_landmark 7 ekf": {"mean_position_error_m": 0.1, "nees_95_fraction": 0.9,
                                        "recoveries": 2, "per_robot": robots},
        "0:300 biased_landmark 12 ekf": {"mean_position_error_m": 0.2, "nees_95_fraction": 0.8,
                                         "recoveries": 1, "per_robot": robots},
    }
    after = {k: dict(v, recoveries=0, per_robot={"1": [0.05, 0.06, 0]}) for k, v in before.items()}
    text = table.table(before, after)
    row = text.splitlines()[2]
    assert row.startswith("| 0:300 | biased_landmark | `ekf` | 2 | 0.150 | 0.150 | 0.85 | 0.85 "
                          "| 3 | 0 ")
    assert "| 0.30 | 0.06 | 3.00 | 1.20 |" in row
    assert script_main("bench/recovery_table")([str(tmp_path / "one.json")]) == 2


# ------------------------------------------------------- consensus re-localization
# Two pairs of landmarks 0.3 m apart (two places) and a single landmark (a third place).
PLACES = {"A1": (4.0, 0.0), "A2": (4.0, 0.3), "B1": (0.0, 4.0), "B2": (0.3, 4.0),
          "C": (-4.0, -1.0)}
VAGUE = np.diag([1.0**2, 0.03**2])  # a range as vague as the MR.CLAM model's at 4 m


def _first_fix(
    belief: np.ndarray, moved: dict[str, np.ndarray], **kw
) -> tuple[float, np.ndarray, np.ndarray] | None:
    """A still robot at the origin reads the landmarks in turn, one every 0.1 s for 20 s,
    every reading passing the gate (gate statistic 1); the map puts the landmarks of
    ``moved`` that far off. The relocalizer is asked after each reading, as the filter
    does, with the belief ``belief``: the time, pose and covariance of its first fix."""
    rng = np.random.default_rng(5)
    track = OdometryTrack(np.array([0.0]), np.zeros(1), np.zeros(1), NOISE)
    reloc = Relocalizer(1, OdometryTrack.motion, **kw)
    names = list(PLACES)
    for k in range(200):
        t = 0.1 * (k + 1)
        name = names[k % len(names)]
        true = np.array(PLACES[name])
        mark = true + moved.get(name, 0.0)
        z = np.array([np.hypot(*true), math.atan2(true[1], true[0])])
        z += rng.normal(0.0, [0.05, 0.005])
        reloc.add(0, t, track.state(t), 0.0, name, mark, z, VAGUE, 1.0, False)
        fix = reloc.propose(0, np.zeros(2), belief, np.eye(3) * 1e-4)
        if fix is not None:
            return t, *fix
    return None


def test_a_lost_robot_whose_readings_pass_the_gate_is_placed_by_their_consensus():
    """Believed 3.6 m off, where the vague ranges let every reading pass the gate (no
    landmark suspect): the readings of three places agree on the true pose within 20 s
    of the first reading; consensus=False leaves the robot lost."""
    found = _first_fix(np.array([3.0, -2.0, 0.0]), {})
    assert found is not None
    t, pose, cov = found
    assert t <= 20.0
    assert np.hypot(*pose[:2]) < 0.3 and abs(pose[2]) < 0.05
    assert pose @ np.linalg.solve(cov, pose) < NEES_BOUND
    assert _first_fix(np.array([3.0, -2.0, 0.0]), {}, consensus=False) is None


@pytest.mark.parametrize("bias", [1.0, 3.0])
def test_one_biased_landmark_does_not_trigger_a_consensus_reset(bias):
    """An accurate belief; the map puts the single landmark C ``bias`` off. With 3 m, a
    pose 1.8 m from the belief explains every reading, C's too (the vague ranges), but
    without C the readings agree with the belief."""
    moved = {"C": np.array([bias, -bias]) / math.sqrt(2.0)}
    assert _first_fix(np.zeros(3), moved) is None


def _one_look(belief: np.ndarray, **kw) -> tuple[np.ndarray, np.ndarray] | None:
    """A still robot at the origin reads the landmarks of :data:`PLACES` in turn, 30
    readings (range std 1 m, bearing std 0.15 rad, as modelled), every one passing the
    gate; the relocalizer is asked once, after the last, with the belief ``belief``."""
    rng = np.random.default_rng(5)
    r = np.diag([1.0, 0.15**2])
    track = OdometryTrack(np.array([0.0]), np.zeros(1), np.zeros(1), NOISE)
    reloc = Relocalizer(1, OdometryTrack.motion, **kw)
    names = list(PLACES)
    for k in range(30):
        t = 0.1 * (k + 1)
        mark = np.array(PLACES[names[k % len(names)]])
        z = np.array([np.hypot(*mark), math.atan2(mark[1], mark[0])])
        reloc.add(0, t, track.state(t), 0.0, names[k % len(names)], mark,
                  z + rng.normal(0.0, np.sqrt(np.diag(r))), r, 1.0, False)
    return reloc.propose(0, np.zeros(2), belief, np.eye(3) * 1e-4)


def test_consensus_needs_four_times_the_fit():
    """The readings explain the fitted pose (at the origin) 4.19 times better than a
    belief 1.70 m off (chi-square ratio, measured: the verdict flips between min_ratio
    4.15 and 4.25), and 3.81 times better than one 1.58 m off: with the default
    min_ratio (4) the first belief is replaced, the second is not."""
    far, near = np.array([1.70, 0.0, 0.0]), np.array([1.58, 0.0, 0.0])
    assert _one_look(far, min_ratio=4.15) is not None and _one_look(far, min_ratio=4.25) is None
    assert _one_look(near, min_ratio=3.77) is not None and _one_look(near, min_ratio=3.85) is None
    fix = _one_look(far)
    assert fix is not None and np.hypot(*fix[0][:2]) < 0.5
    assert _one_look(near) is None
