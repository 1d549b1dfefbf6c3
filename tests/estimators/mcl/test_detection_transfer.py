"""Tests of the collaborative-MCL detection transfer (Fox et al., Eq. 10 / 13)."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.geometry import relative_pose, wrap_angle
from estimators.mcl.detection_transfer import (
    DetectionTransfer,
    RobotDetection,
    TransferConfig,
    detection_from_measurement,
    sample_detected_poses,
    sample_observer_poses,
)
from estimators.mcl.filter import MCLConfig, ParticleFilter
from estimators.mcl.occupancy import OccupancyGrid

POSE_M = np.array([2.0, 4.0, 0.0])
POSE_N = np.array([4.5, 4.3, 1.0])


def room() -> OccupancyGrid:
    """10 m x 6 m walled room, 0.1 m cells."""
    occ = np.zeros((60, 100), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    occ[20:26, 20:30] = True
    return OccupancyGrid(occ, 0.1, (0.0, 0.0))


def localized(grid: OccupancyGrid, pose: np.ndarray, seed: int, n: int = 1000) -> ParticleFilter:
    pf = ParticleFilter(grid, np.random.default_rng(seed), MCLConfig(n_particles=n))
    pf.init_gaussian(pose, np.diag([0.1, 0.1, 0.03]) ** 2)
    return pf


def lost(grid: OccupancyGrid, seed: int, n: int = 2000) -> ParticleFilter:
    return ParticleFilter(grid, np.random.default_rng(seed), MCLConfig(n_particles=n))


def detection(observer=0, target=1, pose_m=POSE_M, pose_n=POSE_N, orientation=True,
              **kw) -> RobotDetection:
    z = relative_pose(pose_m, pose_n)
    return RobotDetection(
        observer=observer, target=target, range=float(z[0]), bearing=float(z[1]),
        range_std=0.3, bearing_std=0.04,
        orientation=float(z[2]) if orientation else None,
        orientation_std=0.1 if orientation else None, **kw,
    )


def mean_error(pf: ParticleFilter, pose: np.ndarray) -> float:
    return float(np.hypot(*(pf.belief().mean[:2] - pose[:2])))


@pytest.mark.parametrize("orientation", [True, False])
def test_detection_by_localized_robot_reduces_lost_robot_error(orientation):
    g = room()
    m, n = localized(g, POSE_M, 1), lost(g, 2)
    before = n.particle_spread(POSE_N)
    assert before > 2.5
    res = DetectionTransfer().apply(detection(orientation=orientation), m, n,
                                    np.random.default_rng(3))
    assert res.applied and res.reason == "applied"
    assert 0.0 < res.false_positive_posterior < 0.5
    after = n.particle_spread(POSE_N)
    assert after < 0.4 * before
    n.resample()
    assert n.particle_spread(POSE_N) < 0.4 * before
    # most of the mass now sits within a metre of the truth
    near = np.hypot(*(n.particles[:, :2] - POSE_N[:2]).T) < 1.0
    assert near.mean() > 0.7
    if orientation:  # the heading is constrained too
        close = near & (np.abs(wrap_angle(n.particles[:, 2] - POSE_N[2])) < 0.4)
        assert close.mean() > 0.6


def test_detection_resolves_a_symmetric_ambiguity():
    # n's belief is bimodal (true pose and its mirror image, as in a symmetric hallway);
    # a detection by a localized robot picks the true mode
    g = room()
    m = localized(g, POSE_M, 1)
    n = ParticleFilter(g, np.random.default_rng(2), MCLConfig(n_particles=2000))
    mirror = np.array([10.0 - POSE_N[0], 6.0 - POSE_N[1], wrap_angle(POSE_N[2] + np.pi)])
    rng = np.random.default_rng(7)
    modes = np.where(rng.random(2000)[:, None] < 0.5, POSE_N, mirror)
    n.set_particles(modes + rng.normal(0.0, [0.15, 0.15, 0.05], (2000, 3)))
    near_true = np.hypot(*(n.particles[:, :2] - POSE_N[:2]).T) < 1.0
    assert 0.4 < n.weights[near_true].sum() < 0.6
    res = DetectionTransfer().apply(detection(), m, n, np.random.default_rng(3))
    assert res.applied and res.false_positive_posterior < 0.05
    kept = n.weights[near_true].sum()
    assert kept > 0.95
    # The mean is the weighted mean of the true mode's particles (std 0.15 m per axis),
    # whose error is Rayleigh with sigma 0.15 / sqrt(ESS) (99.9 % quantile: 3.72 sigma),
    # plus the pull of the mirror's leftover weight (measured: 0.0060 m against 0.021 m).
    pull = (1.0 - kept) * np.hypot(*(mirror[:2] - POSE_N[:2]))
    assert mean_error(n, POSE_N) < 3.72 * 0.15 / np.sqrt(n.ess) + pull


def test_symmetric_update_also_localizes_the_observer():
    g = room()
    m, n = lost(g, 4), localized(g, POSE_N, 5)
    m_before = m.particle_spread(POSE_M)
    n_weights = n.weights.copy()
    cfg = TransferConfig(symmetric=True)
    res = DetectionTransfer(cfg).apply(detection(), m, n, np.random.default_rng(6))
    assert res.applied and res.symmetric_applied
    assert m.particle_spread(POSE_M) < 0.4 * m_before
    # the localized target barely moves: m's uniform belief carries no information, so
    # its weights stay nearly equal (ESS 999.6 of 1000) and its mean stays the sample
    # mean of 1000 draws of std 0.1 m: Rayleigh error, 99.9 % quantile 3.72 * 0.1 / sqrt(ESS)
    # (measured: 0.0011 m against 0.012 m).
    assert not np.array_equal(n.weights, n_weights)
    assert n.ess > 0.99 * n.n_particles
    assert mean_error(n, POSE_N) < 3.72 * 0.1 / np.sqrt(n.ess)


def test_without_symmetric_update_the_observer_is_untouched():
    g = room()
    m, n = lost(g, 4), localized(g, POSE_N, 5)
    w = m.weights.copy()
    DetectionTransfer().apply(detection(), m, n, np.random.default_rng(6))
    np.testing.assert_array_equal(m.weights, w)


def test_repeated_detections_within_lockout_distance_are_ignored():
    g = room()
    m, n = localized(g, POSE_M, 1), lost(g, 2)
    tr = DetectionTransfer(TransferConfig(lockout_distance=2.5))
    rng = np.random.default_rng(3)
    assert tr.apply(detection(), m, n, rng).applied
    w = n.weights.copy()
    for _ in range(2):  # 2 m travelled: still locked
        m.predict_delta((1.0, 0.0, 0.0))
        res = tr.apply(detection(), m, n, rng)
        assert not res.applied and res.reason == "locked"
        np.testing.assert_array_equal(n.weights, w)
    # a different target is not locked
    other = lost(g, 9)
    assert tr.apply(detection(target=2), m, other, rng).applied
    m.predict_delta((0.0, 0.0, 1.0))  # turning in place does not count
    assert tr.apply(detection(), m, n, rng).reason == "locked"
    m.predict_delta((-0.6, 0.0, 0.0))  # reversing does: 2.6 m in total
    assert tr.apply(detection(), m, n, rng).applied
    tr.reset()
    assert tr.apply(detection(), m, n, rng).applied


def test_negative_sightings_and_unknown_robots_are_ignored():
    g = room()
    m, n = localized(g, POSE_M, 1), lost(g, 2)
    w = n.weights.copy()
    tr = DetectionTransfer()
    neg = RobotDetection(observer=0, target=None, range=np.nan, bearing=np.nan, range_std=0.0,
                         bearing_std=0.0, detected=False)
    results = tr.apply_all([neg, detection(target=7)], {0: m, 1: n}, np.random.default_rng(0))
    assert [r.reason for r in results] == ["negative", "unknown_robot"]
    assert tr.apply(detection(detected=False), m, n, np.random.default_rng(0)).reason == "negative"
    np.testing.assert_array_equal(n.weights, w)
    assert tr.apply_all([detection()], {0: m, 1: n}, np.random.default_rng(0))[0].applied


def test_false_positive_against_a_confident_target_is_mostly_discounted():
    g = room()
    m, n = localized(g, POSE_M, 1), localized(g, POSE_N, 2)
    fake = detection(pose_n=np.array([7.0, 1.5, -2.0]))  # n is not there
    res = DetectionTransfer().apply(fake, m, n, np.random.default_rng(3))
    assert res.applied and res.false_positive_posterior > 0.99
    w = n.weights
    assert np.all(np.isfinite(w)) and np.all(w > 0) and w.sum() == pytest.approx(1.0)
    assert mean_error(n, POSE_N) < 0.05
    assert n.ess > 0.9 * n.n_particles


def test_false_positive_against_a_lost_target_keeps_a_valid_particle_set():
    g = room()
    m, n = localized(g, POSE_M, 1), lost(g, 2)
    fake = detection(pose_n=np.array([7.0, 1.5, -2.0]))
    res = DetectionTransfer().apply(fake, m, n, np.random.default_rng(3))
    w = n.weights
    assert np.all(np.isfinite(w)) and np.all(w > 0) and w.sum() == pytest.approx(1.0)
    # the uniform part of the mixture keeps every particle alive: each keeps at least
    # its prior weight times the posterior probability that the detection was false
    assert 0.01 < res.false_positive_posterior < 0.5
    assert w.min() >= res.false_positive_posterior / n.n_particles * (1 - 1e-9)
    n.resample()
    assert n.n_particles == 2000 and np.all(np.isfinite(n.particles))


def test_zero_false_positive_rate_and_disjoint_support_leave_weights_unchanged():
    g = room()
    m, n = localized(g, POSE_M, 1), localized(g, POSE_N, 2)
    w = n.weights.copy()
    cfg = TransferConfig(false_positive_prob=0.0)
    fake = detection(pose_n=np.array([7.0, 1.5, -2.0]))
    res = DetectionTransfer(cfg).apply(fake, m, n, np.random.default_rng(3))
    assert res.applied
    np.testing.assert_array_equal(n.weights, w)  # no NaN from 0/0
    # every sample off the map: nothing to build a density from
    off = detection(pose_n=np.array([30.0, 4.0, 0.0]))
    res = DetectionTransfer(cfg).apply(off, m, n, np.random.default_rng(3))
    assert not res.applied and res.reason == "outside_map"
    np.testing.assert_array_equal(n.weights, w)


def test_tempered_transfer_raises_the_factors_to_the_exponent():
    g = room()
    out = {}
    for exponent in (1.0, 0.25):
        m, n = localized(g, POSE_M, 1), lost(g, 2)
        w0 = n.weights.copy()
        res = DetectionTransfer(TransferConfig(exponent=exponent)).apply(
            detection(), m, n, np.random.default_rng(3))
        assert res.applied
        out[exponent] = n.weights / w0
    # same samples, same tree: tempered factors are the untempered ones ** 0.25
    # (up to the normalization)
    ratio = out[0.25] / out[1.0] ** 0.25
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-6)
    assert out[0.25].max() / out[0.25].min() < out[1.0].max() / out[1.0].min()
    for bad in (0.0, 1.5, float("nan")):
        with pytest.raises(ValueError, match="exponent"):
            TransferConfig(exponent=bad)


def test_sampled_poses_invert_each_other():
    rng = np.random.default_rng(0)
    det = RobotDetection(0, 1, 2.0, 0.4, range_std=1e-6, bearing_std=1e-6, orientation=-0.7,
                         orientation_std=1e-6)
    obs = np.column_stack([rng.uniform(0, 5, 50), rng.uniform(0, 5, 50),
                           rng.uniform(-np.pi, np.pi, 50)])
    tgt = sample_detected_poses(obs, det, rng)
    np.testing.assert_allclose(relative_pose(obs, tgt), np.tile([2.0, 0.4, -0.7], (50, 1)),
                               atol=1e-5)
    back = sample_observer_poses(tgt, det, rng)
    np.testing.assert_allclose(back[:, :2], obs[:, :2], atol=1e-5)
    np.testing.assert_allclose(wrap_angle(back[:, 2] - obs[:, 2]), 0.0, atol=1e-5)
    # without orientation, observers lie on the ring of radius r around the target
    det2 = RobotDetection(0, 1, 2.0, 0.4, range_std=1e-6, bearing_std=1e-6)
    ring = sample_observer_poses(tgt, det2, rng)
    np.testing.assert_allclose(relative_pose(ring, tgt)[:, :2], np.tile([2.0, 0.4], (50, 1)),
                               atol=1e-5)
    # measurement noise is applied at the reported scale
    det3 = RobotDetection(0, 1, 2.0, 0.4, range_std=0.3, bearing_std=0.05)
    z = relative_pose(np.zeros((20000, 3)), sample_detected_poses(np.zeros((20000, 3)), det3, rng))
    assert np.std(z[:, 0]) == pytest.approx(0.3, rel=0.05)
    assert np.std(z[:, 1]) == pytest.approx(0.05, rel=0.05)


def test_transfer_is_deterministic_for_a_seed():
    g = room()
    out = []
    for _ in range(2):
        m, n = localized(g, POSE_M, 1), lost(g, 2)
        DetectionTransfer(TransferConfig(symmetric=True)).apply(
            detection(), m, n, np.random.default_rng(3))
        out.append((m.weights.copy(), n.weights.copy()))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    np.testing.assert_array_equal(out[0][1], out[1][1])


def test_detection_records_validate_their_numbers():
    z = np.array([2.0, 0.3, -0.2])
    det = detection_from_measurement(3, 4, z, np.diag([0.09, 0.0016, 0.01]))
    assert (det.range, det.range_std, det.bearing_std, det.orientation_std) == pytest.approx(
        (2.0, 0.3, 0.04, 0.1))
    with pytest.raises(ValueError, match="range_std"):
        detection_from_measurement(3, 4, z, np.diag([-0.09, 0.0016, 0.01]))
    with pytest.raises(ValueError, match="itself"):
        RobotDetection(1, 1, 1.0, 0.0, 0.1, 0.1)
    with pytest.raises(ValueError, match="orientation_std"):
        RobotDetection(0, 1, 1.0, 0.0, 0.1, 0.1, orientation=0.2)
    with pytest.raises(ValueError, match="false_positive_prob"):
        TransferConfig(false_positive_prob=1.0)


def test_target_samples_with_heading_pi_are_accepted():
    # Headings of +pi (from another wrap convention, or a user's particle set) must land
    # in the transfer's density tree, not raise.
    grid = room()
    target = lost(grid, 2)
    samples = np.array([[4.0, 3.0, np.pi], [4.1, 3.1, -np.pi], [3.9, 2.9, 0.5]] * 20)
    tree = DetectionTransfer(TransferConfig())._tree(samples, target, use_heading=True)
    # each of the three poses (20 copies each, +pi and -pi kept apart) holds a third of
    # the mass in a leaf of its own
    assert tree is not None and tree.integral() == pytest.approx(1.0, abs=1e-12)
    lo, hi, dens = tree.leaves()
    for pose in samples[:3]:
        leaf = np.all((pose >= lo) & (pose < hi), axis=1)
        assert leaf.sum() == 1
        assert dens[leaf][0] * np.prod(hi[leaf] - lo[leaf]) == pytest.approx(1 / 3)
        assert tree.pdf(pose) == dens[leaf][0]
