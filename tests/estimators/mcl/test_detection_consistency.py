"""Tests of the detection consistency measure and the conflict handling helpers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.geometry import relative_pose
from estimators.mcl.density_tree import DensityTree
from estimators.mcl.detection_consistency import (
    ConsistencyConfig,
    assess_detection,
    backtrack,
    detection_bayes_factor,
    main_mode,
    target_pose_density,
    tree_bayes_factor,
    widen,
)
from estimators.mcl.detection_transfer import (
    DetectionTransfer,
    RobotDetection,
    TransferConfig,
    sample_detected_poses,
)
from estimators.mcl.filter import MCLConfig, ParticleFilter
from estimators.mcl.occupancy import OccupancyGrid

BOX = (20.0, 20.0)
OBSERVER = np.array([[10.0, 10.0, 0.4]])


def _grid_points(centre: np.ndarray, half: float, step: float) -> np.ndarray:
    ax = np.arange(-half, half + 1e-9, step)
    gx, gy = np.meshgrid(centre[0] + ax, centre[1] + ax)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def test_target_density_integrates_to_one():
    # k(. | x_m, z) is a density over the target's position: a fine quadrature sums to 1
    z, std = np.array([4.0, 0.3]), np.array([0.3, 0.05])
    pts = _grid_points(np.array([13.6, 11.2]), 2.5, 0.01)
    pts3 = np.c_[pts, np.zeros(len(pts))]
    k = target_pose_density(OBSERVER, pts3, z, std)
    assert k.sum() * 0.01**2 == pytest.approx(1.0, abs=2e-3)


@pytest.mark.parametrize("orientation", [False, True])
def test_bayes_factor_of_an_uninformed_target_is_one(orientation):
    # A target uniform over the box (here an equal-weight grid of poses over all of it):
    # E[k] = 1 / V for any observer whose prediction lies in the box, so B = 1. Grid
    # points far from the prediction add nothing; only the near ones are evaluated, and
    # the mean is taken over the whole grid.
    z = np.array([4.0, 0.3, 0.7]) if orientation else np.array([4.0, 0.3])
    std = np.array([0.3, 0.05, 0.1]) if orientation else np.array([0.3, 0.05])
    step = 0.02
    n_xy = (BOX[0] / step) * (BOX[1] / step)
    xy = _grid_points(np.array([13.6, 11.2]), 2.5, step)  # 4 m ahead, bearing 0.7 world
    heads = np.linspace(-math.pi, math.pi, 128, endpoint=False) if orientation else [0.0]
    pts = np.concatenate([np.c_[xy, np.full(len(xy), h)] for h in heads])
    volume = BOX[0] * BOX[1] * (2 * math.pi if orientation else 1.0)
    b_near = detection_bayes_factor(OBSERVER, pts, z, std, volume)
    b = b_near * len(pts) / (n_xy * len(heads))
    assert b == pytest.approx(1.0, abs=0.01)


def test_bayes_factor_matches_the_gaussian_integral():
    # Observer at (5, 10) facing east sees the target 5 m ahead; with a tight bearing the
    # predicted density is nearly Gaussian N((10, 10), diag(0.3^2, (5 * 0.01)^2)), and for
    # a Gaussian target belief N(mu, s^2 I) the integral of the product is the Gaussian
    # N(mu - (10, 10); 0, Sigma_q + s^2 I): B = V times that.
    observer = np.array([[5.0, 10.0, 0.0]])
    z, std = np.array([5.0, 0.0]), np.array([0.3, 0.01])
    s = 0.5
    volume = BOX[0] * BOX[1]
    for mu in (np.array([10.0, 10.0]), np.array([10.4, 10.3]), np.array([11.5, 9.0])):
        pts = _grid_points(mu, 4 * s, 0.02)
        w = np.exp(-0.5 * np.sum((pts - mu) ** 2, axis=1) / s**2)
        b = detection_bayes_factor(observer, np.c_[pts, np.zeros(len(pts))], z, std, volume,
                                   target_weights=w)
        var = np.array([0.3**2 + s**2, 0.05**2 + s**2])
        d = mu - np.array([10.0, 10.0])
        analytic = volume * math.exp(-0.5 * np.sum(d**2 / var)) / (2 * math.pi
                                                                   * math.sqrt(var.prod()))
        assert b == pytest.approx(analytic, rel=0.03)
    # far apart: the factor is essentially zero (the beliefs contradict each other)
    pts = _grid_points(np.array([16.0, 4.0]), 2.0, 0.05)
    far = detection_bayes_factor(observer, np.c_[pts, np.zeros(len(pts))], z, std, volume)
    assert far < 1e-6


def test_tree_bayes_factor_of_an_uninformed_target_is_about_one():
    rng = np.random.default_rng(0)
    det = RobotDetection(0, 1, range=4.0, bearing=0.3, range_std=0.3, bearing_std=0.05)
    samples = sample_detected_poses(np.repeat(OBSERVER, 1000, axis=0), det, rng)[:, :2]
    tree = DensityTree(samples, low=np.zeros(2), high=np.array(BOX))
    target = _grid_points(np.array([10.0, 10.0]), 10.0 - 0.01, 0.02)  # uniform, as a grid
    b = tree_bayes_factor(tree.pdf(target), np.full(len(target), 1 / len(target)),
                          tree.volume)
    assert b == pytest.approx(1.0, abs=0.02)


def test_main_mode_finds_the_heaviest_cluster():
    rng = np.random.default_rng(1)
    a = rng.normal([3.0, 3.0], 0.2, size=(700, 2))
    b = rng.normal([15.0, 12.0], 0.2, size=(300, 2))
    xy = np.concatenate([a, b])
    centre, mode = main_mode(xy, np.full(1000, 1e-3), 2.0)
    assert np.hypot(*(centre - [3.0, 3.0])) < 0.3  # inside the heavier cluster
    assert mode[:700].all() and not mode[700:].any()


def _confident(rng, centre, n=1000, sd=0.2):
    return rng.normal(centre, sd, size=(n, 2))


def test_assessment_separates_agreement_conflict_and_ignorance():
    rng = np.random.default_rng(2)
    cfg = ConsistencyConfig()
    xy = _confident(rng, [5.0, 5.0])
    w = np.full(len(xy), 1 / len(xy))
    ones = np.ones(len(xy))
    # agreement: the factors favour the robot's own mode
    agree = assess_detection(xy, w, 1 + ones * 50, 500.0, cfg)
    assert agree.confident and not agree.conflict
    # contradiction: B far below 1 for a confident robot
    assert assess_detection(xy, w, ones * 1e-5, 1e-4, cfg).conflict
    # a few stray particles far away agree with the observer: the transfer would move it
    stray = xy.copy()
    stray[:5] = [15.0, 15.0]
    factors = np.where(np.arange(len(xy)) < 5, 1e3, 1e-5)
    moved = assess_detection(stray, w, factors, 5.0, cfg)
    assert moved.mode_mass_after < 0.01 and moved.conflict
    # a lost robot is never in conflict, whatever the detection says
    lost = rng.uniform(0, 20, size=(1000, 2))
    assert not assess_detection(lost, w, factors, 1e-4, cfg).conflict


def test_widen_tops_up_a_minority_hypothesis_without_stacking():
    rng = np.random.default_rng(3)
    xy = _confident(rng, [5.0, 5.0])
    parts = np.c_[xy, np.zeros(len(xy))]
    w = np.full(len(xy), 1 / len(xy))
    claimed = np.c_[_confident(rng, [15.0, 12.0], n=100), np.zeros(100)]
    p1, w1, placed = widen(parts, w, claimed, 0.05, 2.0, rng)
    near = np.hypot(p1[:, 0] - 15, p1[:, 1] - 12) < 2
    assert placed == 50 and w1[near].sum() == pytest.approx(0.05)
    own = np.hypot(p1[:, 0] - 5, p1[:, 1] - 5) < 2
    assert w1[own].sum() == pytest.approx(0.95)
    p2, w2, placed2 = widen(p1, w1, claimed, 0.05, 2.0, rng)  # again: nothing to add
    assert placed2 == 0 and np.allclose(w2, w1) and np.array_equal(p2, p1)


def test_backtrack_inverts_the_odometry():
    rng = np.random.default_rng(4)
    deltas = np.c_[rng.uniform(0, 0.5, 30), rng.uniform(-0.05, 0.05, 30),
                   rng.uniform(-0.3, 0.3, 30)]
    pose = np.array([2.0, 3.0, 0.5])
    truth = []
    for dx, dy, dth in deltas:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose = np.array([pose[0] + c * dx - s * dy, pose[1] + s * dx + c * dy, pose[2] + dth])
        truth.append(pose)
    back = backtrack(pose, deltas)
    d = back - np.array(truth)
    d[:, 2] = (d[:, 2] + math.pi) % (2 * math.pi) - math.pi
    assert np.abs(d).max() < 1e-9
    assert backtrack(np.stack([pose, pose]), deltas).shape == (2, 30, 3)


@pytest.mark.parametrize("bad", [dict(min_bayes_factor=-1.0), dict(mode_radius=0.0),
                                 dict(confident_mass=1.5), dict(widen_mass=0.6)])
def test_consistency_config_rejects_bad_values(bad):
    name = next(iter(bad))
    with pytest.raises(ValueError, match=name):
        ConsistencyConfig(**bad)


def _room() -> OccupancyGrid:
    occ = np.zeros((100, 200), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    return OccupancyGrid(occ, 0.1, (0.0, 0.0))


def test_checked_transfer_does_not_move_a_confident_robot_to_stray_particles():
    # Robot 1 is localized at its true pose but, as with any injection of random
    # particles, holds a few strays; a confident observer on a wrong pose detects it and
    # predicts it where the strays are. Fox's transfer follows the strays; the checked
    # transfer reports a conflict and leaves the belief alone.
    grid = _room()
    truth_m, truth_n = np.array([4.0, 5.0, 0.0]), np.array([7.0, 5.0, 0.0])
    wrong_m = np.array([12.0, 2.0, 0.0])  # where the observer believes it is
    z = relative_pose(truth_m, truth_n)
    det = RobotDetection(0, 1, range=float(z[0]), bearing=float(z[1]), range_std=0.3,
                         bearing_std=0.04, orientation=float(z[2]), orientation_std=0.1)
    moved = {}
    for name, cfg in (("fox", TransferConfig()),
                      ("checked", TransferConfig(consistency=ConsistencyConfig()))):
        m = ParticleFilter(grid, np.random.default_rng(5), MCLConfig(n_particles=1000))
        m.init_gaussian(wrong_m, np.diag([0.1, 0.1, 0.03]) ** 2)
        n = ParticleFilter(grid, np.random.default_rng(6), MCLConfig(n_particles=1000))
        n.init_gaussian(truth_n, np.diag([0.1, 0.1, 0.03]) ** 2)
        parts = n.particles.copy()
        parts[:5] = [15.0, 2.0, 0.0]  # the strays, where the observer's claim points
        n.set_particles(parts)
        x0, y0, x1, y1 = grid.bounds
        exact = detection_bayes_factor(m.particles, n.particles, np.asarray(z),
                                       np.array([0.3, 0.04, 0.1]),
                                       (x1 - x0) * (y1 - y0) * 2 * np.pi, m.weights, n.weights)
        res = DetectionTransfer(cfg).apply(det, m, n, np.random.default_rng(7))
        moved[name] = (res, float(np.hypot(*(n.mean_pose()[:2] - truth_n[:2]))))
    assert moved["fox"][0].applied and moved["fox"][1] > 5.0
    res, err = moved["checked"]
    assert not res.applied and res.reason == "conflict" and err < 0.2
    # The strays agree with the claim: the Bayes factor (the transfer's density tree;
    # 65.5 against the Gaussian integral's 66.0) is far above min_bayes_factor, and the
    # conflict is the move of the main mode's weight onto the strays.
    assert res.bayes_factor == pytest.approx(exact, rel=0.05)
    assert res.bayes_factor > ConsistencyConfig().min_bayes_factor


def test_unchecked_transfer_moves_a_confident_robot_to_the_hypothesis_it_keeps():
    # The same confident target, its few particles where the detection puts it: with
    # ``check=False`` (the caller knows the detection picks a hypothesis the target keeps,
    # as a kept symmetric copy) the transfer is applied and the weight moves there.
    grid = _room()
    observer_at, target_at, kept = (np.array([4.0, 5.0, 0.0]), np.array([7.0, 5.0, 0.0]),
                                    np.array([15.0, 2.0, 0.0]))
    z = relative_pose(observer_at, kept)
    det = RobotDetection(0, 1, range=float(z[0]), bearing=float(z[1]), range_std=0.3,
                         bearing_std=0.04, orientation=float(z[2]), orientation_std=0.1)
    results = {}
    for check in (True, False):
        m = ParticleFilter(grid, np.random.default_rng(5), MCLConfig(n_particles=1000))
        m.init_gaussian(observer_at, np.diag([0.1, 0.1, 0.03]) ** 2)
        n = ParticleFilter(grid, np.random.default_rng(6), MCLConfig(n_particles=1000))
        n.init_gaussian(target_at, np.diag([0.1, 0.1, 0.03]) ** 2)
        parts = n.particles.copy()
        parts[:5] = kept
        n.set_particles(parts)
        transfer = DetectionTransfer(TransferConfig(consistency=ConsistencyConfig()))
        res = transfer.apply(det, m, n, np.random.default_rng(7), check=check)
        results[check] = (res, float(n.weights[:5].sum()))
    assert not results[True][0].applied and results[True][0].reason == "conflict"
    assert results[True][1] == pytest.approx(5e-3)
    res, kept_mass = results[False]
    assert res.applied and kept_mass > 0.5


def test_a_robot_split_between_symmetric_copies_is_confident_about_the_set():
    # half its weight on each of two copies of its pose (a symmetric map it cannot tell)
    rng = np.random.default_rng(3)
    cfg = ConsistencyConfig()
    xy = np.concatenate([_confident(rng, [5.0, 5.0], 500), _confident(rng, [15.0, 15.0], 500)])
    w = np.full(1000, 1e-3)
    both = np.ones(1000, dtype=bool)
    first = np.arange(1000) < 500
    # a detection that picks one copy keeps the mass inside the set: no conflict
    picks = np.where(first, 50.0, 1e-3)
    assert not assess_detection(xy, w, picks, 25.0, cfg, hypotheses=both).conflict
    # one that puts it on neither (a false positive) is a conflict for the set ...
    stray = xy.copy()
    stray[:5] = [5.0, 15.0]
    elsewhere = np.where(np.arange(1000) < 5, 1e3, 1e-5)
    res = assess_detection(stray, w, elsewhere, 1e-3, cfg, hypotheses=both)
    assert res.confident and res.conflict
    # ... which the main mode alone (half the weight: not confident) would have let through
    assert not assess_detection(stray, w, elsewhere, 1e-3, cfg).conflict
    with pytest.raises(ValueError, match="hypotheses"):
        assess_detection(xy, w, picks, 25.0, cfg, hypotheses=both[:10])


def _mode_with_mass(mass: float, n: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    """Particles of which ``mass`` of the weight sits in one tight cluster, the rest 10 m
    away: the main mode holds exactly ``mass``."""
    rng = np.random.default_rng(3)
    k = int(round(mass * n))
    xy = np.concatenate([rng.normal([5.0, 5.0], 0.2, (k, 2)), rng.normal([15.0, 15.0], 0.2,
                                                                          (n - k, 2))])
    return xy, np.full(n, 1.0 / n)


@pytest.mark.parametrize(("bayes_factor", "conflict"), [(0.095, True), (0.105, False)])
def test_default_bayes_factor_threshold(bayes_factor, conflict):
    """A confident robot: a detection with a Bayes factor 5 % under the default 0.1
    conflicts with it, one 5 % over does not (a transfer that keeps its mode)."""
    xy, w = _mode_with_mass(0.9)
    res = assess_detection(xy, w, np.ones(len(w)), bayes_factor, ConsistencyConfig())
    assert res.confident and res.mode_mass_after == pytest.approx(0.9)
    assert res.conflict is conflict


@pytest.mark.parametrize(("mass", "confident"), [(0.58, False), (0.62, True)])
def test_default_confident_mass(mass, confident):
    """A main mode holding 0.58 of the weight is not confident (no conflict however
    unlikely the detection), one holding 0.62 is (the default bound is 0.6)."""
    xy, w = _mode_with_mass(mass)
    res = assess_detection(xy, w, np.ones(len(w)), 1e-3, ConsistencyConfig())
    assert res.mode_mass == pytest.approx(mass)
    assert res.confident is confident and res.conflict is confident


@pytest.mark.parametrize(("kept", "conflict"), [(0.47, True), (0.53, False)])
def test_default_move_fraction(kept, conflict):
    """A confident robot (0.9 of its weight in its mode) whose would-be transfer keeps
    ``kept`` of that share in the mode: below half (the default) it is a conflict, above
    not, whatever the Bayes factor (1 here)."""
    xy, w = _mode_with_mass(0.9)
    mode = np.arange(len(w)) < 900
    # factor f outside the mode: after = 0.9 / (0.9 + 0.1 f) = kept * 0.9
    f = (1.0 / kept - 0.9) / 0.1
    res = assess_detection(xy, w, np.where(mode, 1.0, f), 1.0, ConsistencyConfig())
    assert res.mode_mass_after == pytest.approx(0.9 * kept)
    assert res.conflict is conflict


def test_default_mode_radius():
    """Particles 1.9 m from the main mode's centre belong to it, 2.1 m away not (the
    default radius is 2 m)."""
    xy = np.array([[5.0, 5.0]] * 900 + [[6.9, 5.0]] * 50 + [[7.1, 5.0]] * 50)
    res = assess_detection(xy, np.full(1000, 1e-3), np.ones(1000), 1.0, ConsistencyConfig())
    assert res.mode_mass == pytest.approx(0.95)
