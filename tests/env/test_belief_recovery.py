"""The EKF's belief stays honest when robots misbehave: gate lock-out recovery, false
detections, and a robot pushing against a wall (bumper-aware prediction)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

import coop_loc_env
from coop_loc_env.backends.base import CONTACT_CORRELATION_STEPS, contact_variance
from estimators.ekf import GateMonitor, PoseEKF, chi2_threshold, relative_measurement
from estimators.team_ekf import MotionNoise, OdometryTrack, TeamEKF

NEES_BOUND = chi2_threshold(0.999, 3)
R_GPS = np.eye(2)[None] * 0.3**2


def _nees(mean, cov, truth) -> float:
    d = np.asarray(mean, dtype=float) - truth
    d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
    return float(d @ np.linalg.solve(cov, d))


def _lost_filter(**kw) -> PoseEKF:
    """One robot believed at (10, 0) within 0.2 m while it stands at the origin."""
    return PoseEKF(np.array([[10.0, 0.0, 0.0]]), np.diag([0.04, 0.04, 0.01]), **kw)


def test_a_single_dgps_outlier_is_still_rejected():
    ekf = PoseEKF(np.zeros((1, 3)), np.diag([0.04, 0.04, 0.01]))
    assert not ekf.update_position([0], np.array([[8.0, -6.0]]), R_GPS).any()
    np.testing.assert_array_equal(ekf.mean, np.zeros((1, 3)))
    # A good fix afterwards is fused and restarts the count: two more outliers stay rejected.
    assert ekf.update_position([0], np.array([[0.1, 0.0]]), R_GPS).all()
    for _ in range(2):
        assert not ekf.update_position([0], np.array([[8.0, -6.0]]), R_GPS).any()
    assert np.hypot(*ekf.mean[0, :2]) < 0.2


def test_consecutive_dgps_rejections_recover_the_position():
    ekf = _lost_filter()
    rng = np.random.default_rng(0)
    accepted = [bool(ekf.update_position([0], rng.normal(0, 0.3, (1, 2)), R_GPS)[0])
                for _ in range(3)]
    assert accepted == [False, False, True]
    assert ekf.monitor.recoveries == 1
    assert np.hypot(*ekf.mean[0, :2]) < 1.0
    # The belief now covers its error, and later fixes pass the gate and refine it.
    assert _nees(ekf.mean[0], ekf.cov[0], np.zeros(3)) < NEES_BOUND
    for _ in range(5):
        assert ekf.update_position([0], rng.normal(0, 0.3, (1, 2)), R_GPS).all()
    assert np.hypot(*ekf.mean[0, :2]) < 0.4


def test_a_run_of_scattered_outliers_does_not_trigger_a_recovery():
    """Three multipath fixes in a row, metres apart: they disagree with each other, so the
    filter keeps its belief (a drifted filter sees the same innovation again and again)."""
    ekf = PoseEKF(np.zeros((1, 3)), np.diag([0.04, 0.04, 0.01]))
    for z in ([[-6.5, 5.5]], [[5.3, -9.5]], [[-8.5, 2.3]], [[7.0, 7.0]]):
        assert not ekf.update_position([0], np.array(z), R_GPS).any()
    np.testing.assert_array_equal(ekf.mean, np.zeros((1, 3)))
    assert ekf.monitor.recoveries == 0


def test_compass_lockout_recovers_and_can_be_switched_off():
    for recover_after, recovered in ((3, True), (None, False)):
        ekf = PoseEKF(np.array([[0.0, 0.0, 2.0]]), np.diag([0.01, 0.01, 1e-4]),
                      recover_after=recover_after)
        for _ in range(8):
            ekf.update_heading([0], np.array([0.0]), np.array([0.01]))
        assert (abs(ekf.mean[0, 2]) < 0.3) == recovered
        assert (abs(ekf.mean[0, 2]) == 2.0) != recovered


def test_gate_monitor_counts_per_robot_and_channel_and_checks_its_argument():
    mon = GateMonitor(2, recover_after=2)
    assert not mon.record("position", np.array([0, 1]), np.array([False, True])).any()
    assert not mon.record("heading", np.array([0]), np.array([False])).any()
    np.testing.assert_array_equal(
        mon.record("position", np.array([0, 1]), np.array([False, False])), [True, False]
    )
    assert mon.counts["position"].tolist() == [0, 1]
    assert mon.record_one("position", 1, False) and mon.recoveries == 2
    with pytest.raises(ValueError, match="recover_after"):
        GateMonitor(2, recover_after=0)


@pytest.mark.parametrize(("d2", "agree"), [(11.5, True), (14.5, False)])
def test_rejections_agree_up_to_the_0999_quantile(d2, agree):
    """Two rejected fixes in a row whose difference has the chi-square statistic ``d2``
    (2 dof, covariance ``S + S_prev``) extend one run up to the 0.999 quantile, 13.8: 11.5
    (past the 0.99 quantile, 9.2) agrees and recovers, 14.5 (below the 0.9999 one, 18.4)
    starts a new run."""
    mon = GateMonitor(1, recover_after=2)
    s = np.eye(2)[None]
    first = mon.record("position", np.array([0]), np.array([False]), np.zeros((1, 2)), s)
    nu = np.array([[math.sqrt(2.0 * d2), 0.0]])  # d2 = |nu - 0|^2 / 2 with S + S_prev = 2 I
    second = mon.record("position", np.array([0]), np.array([False]), nu, s)
    assert not first[0] and second[0] is np.bool_(agree)
    assert mon.counts["position"][0] == (0 if agree else 1)


def _rbo(xa, xb) -> np.ndarray:
    return relative_measurement(np.asarray(xa, float), np.asarray(xb, float))[0]


R_DET = np.diag([0.05**2, 0.02**2, 0.05**2])[None]


def test_relative_gate_uses_the_uninflated_innovation_covariance():
    """Covariance intersection inflates both priors (by 1/w, 1/(1 - w)); gating on that
    inflated S accepted detections 1 m off two beliefs of 0.2 m std."""
    truth = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    ekf = PoseEKF(truth.copy(), np.diag([0.04, 0.04, 1e-3]))
    z = _rbo(truth[:1], truth[1:]) + [1.0, 0.0, 0.0]
    assert not ekf.update_relative([0], [1], z, R_DET).any()
    np.testing.assert_array_equal(ekf.mean, truth)


def test_a_false_detection_does_not_move_an_isolated_robot():
    """Robot 1 is lost (10 m std): a detection far from its belief waits for a second,
    agreeing one before it moves the robot by metres."""
    truth = np.array([[0.0, 0.0, 0.0], [4.0, 1.0, 0.3]])
    cov = np.stack([np.diag([0.01, 0.01, 1e-4]), np.diag([100.0, 100.0, 1e-2])])
    ekf = PoseEKF(np.array([[0.0, 0.0, 0.0], [12.0, -6.0, 0.3]]), cov)
    false_z = _rbo(truth[:1], [[-3.0, 7.0, 1.0]])  # a false positive somewhere else
    assert not ekf.update_relative([0], [1], false_z, R_DET).any()
    np.testing.assert_allclose(ekf.mean[1], [12.0, -6.0, 0.3], atol=1e-12)
    # A genuine detection disagrees with the false one: held as well.
    ekf.predict(np.zeros(2), np.zeros(2), 0.1, 0.0, 0.0)
    genuine = _rbo(truth[:1], truth[1:])
    assert not ekf.update_relative([0], [1], genuine, R_DET).any()
    # A second genuine one agrees with the first: fused.
    ekf.predict(np.zeros(2), np.zeros(2), 0.1, 0.0, 0.0)
    assert ekf.update_relative([0], [1], genuine, R_DET).all()
    assert np.hypot(*(ekf.mean[1, :2] - truth[1, :2])) < 0.5


def test_false_detections_of_both_robots_must_agree_in_relative_orientation_too():
    """Robot 0 sees robot 1 where it is not, then robot 1 sees robot 0 at the mirrored
    place (the positions agree) but with the relative orientation of another pose."""
    truth = np.array([[0.0, 0.0, 0.0], [4.0, 1.0, 0.3]])
    cov = np.stack([np.diag([0.01, 0.01, 1e-4]), np.diag([100.0, 100.0, 1e-2])])
    start = np.array([[0.0, 0.0, 0.0], [4.0, 1.0, 0.3]])
    ekf = PoseEKF(start.copy(), cov)
    ghost = np.array([[-3.0, 7.0, 0.3]])
    assert not ekf.update_relative([0], [1], _rbo(truth[:1], ghost), R_DET).any()
    ekf.predict(np.zeros(2), np.zeros(2), 0.1, 0.0, 0.0)
    mirrored = _rbo(ghost, truth[:1])
    mirrored[0, 2] += 0.8  # the orientation the ghost pose would not give
    assert not ekf.update_relative([1], [0], mirrored, R_DET).any()
    np.testing.assert_allclose(ekf.mean, start, atol=1e-12)


def test_agreeing_detections_recover_a_robot_the_gate_locked_out():
    """Robot 1 believes it is 6 m from where it is, within 0.1 m: every detection fails
    the gate, but three that agree move it there with a covariance covering the jump."""
    truth = np.array([[0.0, 0.0, 0.0], [4.0, 1.0, 0.3]])
    cov = np.stack([np.diag([0.01, 0.01, 1e-4]), np.diag([0.01, 0.01, 1e-3])])
    ekf = PoseEKF(np.array([[0.0, 0.0, 0.0], [10.0, 1.0, 0.3]]), cov)
    z = _rbo(truth[:1], truth[1:])
    for _ in range(2):  # overruling the belief takes three agreeing detections
        assert not ekf.update_relative([0], [1], z, R_DET).any()
        ekf.predict(np.zeros(2), np.zeros(2), 0.1, 0.0, 0.0)
    assert ekf.update_relative([0], [1], z, R_DET).all()
    assert np.hypot(*(ekf.mean[1, :2] - truth[1, :2])) < 0.3
    assert _nees(ekf.mean[1], ekf.cov[1], truth[1]) < NEES_BOUND
    # The well-localized observer did not move.
    assert np.hypot(*ekf.mean[0, :2]) < 1e-9


def test_team_ekf_recovers_from_landmark_lockout():
    tracks = [OdometryTrack(np.array([0.0]), np.zeros(1), np.zeros(1),
                            MotionNoise(1e-4, 0, 1e-4, 0))]
    r = np.diag([0.05**2, 0.01**2])
    lm = np.array([3.0, 4.0])
    # The robot is really at the origin: range 5, bearing atan2(4, 3). Readings of one
    # landmark, however many, do not prove the filter lost (the landmark may be wrong).
    ekf = TeamEKF(tracks, np.array([[2.0, 0.0, 0.0]]), np.eye(3) * 1e-3, 0.0)
    z = np.array([5.0, math.atan2(4.0, 3.0)])
    assert not any(ekf.update_landmark(0, lm, z, r, t=0.1 * k) for k in range(1, 6))
    assert ekf.rejected[0] == 5 and ekf.relocalizer.recoveries == 0
    # Two landmarks in turn that agree on one pose do; recover_after=None never recovers.
    marks = (lm, np.array([-4.0, 3.0]))
    for recover_after, found in ((3, True), (None, False)):
        ekf = TeamEKF(tracks, np.array([[2.0, 0.0, 0.0]]), np.eye(3) * 1e-3, 0.0,
                      recover_after=recover_after)
        for k in range(1, 21):
            m = marks[k % 2]
            z = np.array([np.hypot(*m), math.atan2(m[1], m[0])])
            ekf.update_landmark(0, m, z, r, t=0.1 * k)
        assert (np.hypot(*ekf.x[:2]) < 0.2) == found
        assert (_nees(ekf.x, ekf.P, np.zeros(3)) < NEES_BOUND) == found


def test_contact_variance_grows_like_a_constant_unknown_velocity():
    d = np.array([0.1])
    total = sum(contact_variance(d, np.array([k]))[0] for k in range(1, 6))
    assert total == pytest.approx((5 * 0.1) ** 2)
    k = CONTACT_CORRELATION_STEPS
    assert contact_variance(d, np.array([k + 5]))[0] == contact_variance(d, np.array([k]))[0]


def test_robot_pushing_against_a_wall_keeps_an_honest_belief():
    """Full speed into the west boundary for 20 s: the wheels report 1 m/s while the robot
    stands still. The bumper tells the filter, whose covariance covers the error."""
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2,
                                    start_poses=((1.0, 20.0, math.pi), (10.0, 8.0, 0.0)))
    env.reset(seed=3)
    nees, errors, pressed = [], [], []
    for _ in range(200):
        _, _, _, _, infos = env.step({"robot_0": np.array([1.0, 0.0]),
                                      "robot_1": np.array([0.0, 0.0])})
        info = infos["robot_0"]
        nees.append(_nees(info["est_pose"], info["pose_cov"], np.asarray(info["true_pose"])))
        errors.append(info["position_error"])
        pressed.append(bool(env.last_readings.bumper[0]))
    assert not pressed[0] and all(pressed[10:])
    assert not env.last_readings.bumper[1]
    # Two-sided. Overconfidence: 95 % of the steps pressed inside the 99.9 % bound (all of
    # them here). The time mean of the NEES counts 19 independent samples (one per 1 Hz
    # DGPS fix; steps in between repeat the same error), so a 3-dof filter keeps it within
    # chi2(57) / 19 at 99.9 %: at most 5.20. The contact model bounds the slip by its
    # largest value, a variance 3 times that of a uniform one, so the lower bound 1.49 is
    # divided by 3: 0.50. An inflated covariance fails it (measured 0.84; seeds 3-8 give
    # 0.77-3.94, mean 1.52).
    pressed_nees = np.array(nees[10:])
    assert np.mean(pressed_nees < NEES_BOUND) >= 0.95
    lo, hi = chi2.ppf(0.0005, 3 * 19) / 19 / 3, chi2.ppf(0.9995, 3 * 19) / 19
    assert lo <= pressed_nees.mean() <= hi, (pressed_nees.mean(), lo, hi)
    assert max(errors[100:]) < 1.0
