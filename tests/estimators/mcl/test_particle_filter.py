"""Tests of the occupancy grid and the Monte Carlo localization particle filter.

One file: every test drives the same simulated room and robot (``room``, ``Robot``,
``run`` below).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom, chi2

from estimators.geometry import wrap_angle
from estimators.mcl.filter import (
    MCLConfig,
    ParticleFilter,
    ParticleMotionNoise,
    belief_feature_names,
    compose_odometry,
    kld_sample_bound,
    low_variance_indices,
)
from estimators.mcl.occupancy import OccupancyGrid

RES = 0.1
MAX_RANGE = 8.0
BEAMS = np.linspace(-np.pi, np.pi, 30, endpoint=False)
WAYPOINTS = np.array(
    [[1, 1], [4, 1.5], [5.5, 1.6], [7.5, 2.5], [9, 2.5], [9, 5], [8, 5.3], [5.5, 4.5], [3, 4.5],
     [1, 4.5], [1, 3]]
)


def room(res: float = RES) -> OccupancyGrid:
    """A 10 m x 6 m walled room with boxes placed without any symmetry."""
    nx, ny = int(round(10.0 / res)), int(round(6.0 / res))
    occ = np.zeros((ny, nx), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    boxes = [(2.0, 2.0, 3.0, 2.6), (6.5, 3.2, 7.0, 4.2), (4.5, 0.0, 4.8, 1.2), (8.0, 1.0, 9.0, 1.5),
             (3.5, 5.4, 4.5, 6.0), (5.8, 2.8, 6.1, 3.1), (9.5, 5.5, 10.0, 6.0)]
    for x0, y0, x1, y1 in boxes:
        rows = slice(int(round(y0 / res)), int(round(y1 / res)))
        occ[rows, int(round(x0 / res)):int(round(x1 / res))] = True
    return OccupancyGrid(occ, res, (0.0, 0.0))


class Robot:
    """A simulated robot following the waypoint loop, with noisy odometry and laser."""

    def __init__(self, grid: OccupancyGrid, seed: int, pose=(1.0, 1.0, 0.0), wp: int = 0):
        self.grid = grid
        self.rng = np.random.default_rng(seed)
        self.pose = np.array(pose, dtype=float)
        self.wp = wp

    def step(self, dt: float = 0.2) -> tuple[float, float, float, np.ndarray]:
        tgt = WAYPOINTS[self.wp % len(WAYPOINTS)]
        d = tgt - self.pose[:2]
        if np.hypot(*d) < 0.3:
            self.wp += 1
            d = WAYPOINTS[self.wp % len(WAYPOINTS)] - self.pose[:2]
        err = wrap_angle(np.arctan2(d[1], d[0]) - self.pose[2])
        w = float(np.clip(2 * err, -1.5, 1.5))
        v = 0.5 if abs(err) < 0.5 else 0.1
        th, dth = self.pose[2], w * dt
        self.pose = self.pose + [v * dt * np.cos(th + dth / 2), v * dt * np.sin(th + dth / 2), dth]
        self.pose[2] = wrap_angle(self.pose[2])
        vm = v * (1 + 0.05 * self.rng.standard_normal())
        wm = w + 0.05 * self.rng.standard_normal()
        z = self.grid.simulate_scan(self.pose, BEAMS, MAX_RANGE)
        z = np.clip(z + 0.03 * self.rng.standard_normal(z.size), 0.0, MAX_RANGE)
        return vm, wm, dt, z


def run(pf: ParticleFilter, robot: Robot, steps: int, beam: bool = False) -> list[float]:
    spread = []
    for _ in range(steps):
        pf.resample_if_needed()
        v, w, dt, z = robot.step()
        pf.predict_odometry(v, w, dt)
        if beam:
            pf.update_beam(z, BEAMS, MAX_RANGE, cone_half_width=np.deg2rad(5))
        else:
            pf.update_likelihood_field(z, BEAMS, MAX_RANGE)
        spread.append(pf.particle_spread(robot.pose))
    return spread


# ------------------------------------------------------------------ occupancy grid
def test_grid_conversions_and_free_space():
    g = room()
    assert g.bounds == (0.0, 0.0, 10.0, 6.0)
    cells = g.world_to_cell(np.array([[0.05, 0.05], [9.99, 5.99], [-0.01, 1.0]]))
    np.testing.assert_array_equal(cells, [[0, 0], [99, 59], [-1, 10]])
    np.testing.assert_allclose(g.cell_to_world(np.array([3, 4])), [0.35, 0.45])
    np.testing.assert_array_equal(
        g.is_free(np.array([[1.0, 1.0], [2.5, 2.3], [0.05, 3.0], [11.0, 3.0]])),
        [True, False, False, False],
    )
    pts = g.sample_free(5000, np.random.default_rng(0))
    assert g.is_free(pts).all()
    # uniform over free space: the share left of x = 4.5 matches its free-area share
    free = ~g.occupied
    share = free[:, :45].sum() / free.sum()
    assert abs(np.mean(pts[:, 0] < 4.5) - share) < 4 * np.sqrt(share * (1 - share) / 5000)


def test_distance_field_is_metric_edt():
    occ = np.zeros((20, 30), dtype=bool)
    occ[10, 15] = True
    g = OccupancyGrid(occ, 0.5, (-1.0, 2.0))
    d = g.distance_field()
    assert d[10, 15] == 0.0
    assert d[10, 18] == pytest.approx(1.5)
    assert d[13, 19] == pytest.approx(2.5)
    padded = g.distance_field(pad_cells=4)
    assert padded.shape == (28, 38)
    np.testing.assert_allclose(padded[4:-4, 4:-4], d)


def test_ray_casting_matches_brute_force_marching():
    g = room()
    rng = np.random.default_rng(1)
    origins = g.sample_free(200, rng)
    angles = rng.uniform(-np.pi, np.pi, 200)
    ranges = g.cast_rays(origins, angles, MAX_RANGE)
    ts = np.arange(0.0, MAX_RANGE, 0.002)
    for o, a, r in zip(origins, angles, ranges, strict=True):
        pts = o + ts[:, None] * np.array([np.cos(a), np.sin(a)])
        blocked = ~g.is_free(pts)
        truth = ts[np.argmax(blocked)] if blocked.any() else MAX_RANGE
        assert truth - 0.005 <= r <= truth + 0.005
    # known geometry: from (1, 1) looking +x the box at x = 4.5 (y in [0, 1.2]) is 3.5 m away
    r = g.simulate_scan(np.array([1.0, 1.0, 0.0]), np.array([0.0, np.pi / 2]), MAX_RANGE)
    assert r[0] == pytest.approx(3.5, abs=0.6 * RES)
    assert r[1] == pytest.approx(4.9, abs=0.6 * RES)


def test_rasterized_shapes_match_their_geometry():
    hexagon = np.array([[5 + 2 * np.cos(a), 3 + 2 * np.sin(a)] for a in np.arange(6) * np.pi / 3])
    g = OccupancyGrid.from_shapes(
        (10.0, 6.0), 0.05, circles=[((2.0, 2.0), 0.5)],
        segments=[((7.0, 1.0), (9.0, 1.0), 0.0)], polygons=[hexagon],
    )
    assert g.shape == (120, 200) and g.bounds == (0.0, 0.0, 10.0, 6.0)
    pts = np.array([[2.0, 2.0], [2.4, 2.0], [2.0, 2.6], [7.5, 1.0], [7.5, 1.1], [5.0, 3.0],
                    [6.7, 3.0], [5.0, 4.8], [0.01, 3.0], [5.0, 5.99]])
    np.testing.assert_array_equal(
        g.is_free(pts), [False, False, True, False, True, False, False, True, False, False]
    )
    # filled areas: disk pi r^2 and hexagon (3 sqrt(3) / 2) R^2, up to cell discretization
    inner = g.occupied[1:-1, 1:-1]
    cell = 0.05**2
    hex_area = 1.5 * np.sqrt(3) * 4
    thin_wall = 2.0 * 0.05 * 2  # two rows of cells
    expected = np.pi * 0.25 + hex_area + thin_wall
    assert inner.sum() * cell == pytest.approx(expected, rel=0.02)
    # a thin diagonal wall blocks every ray that crosses it
    wall = OccupancyGrid.from_shapes((4.0, 4.0), 0.1, segments=[((0.5, 0.5), (3.5, 3.5), 0.0)])
    rng = np.random.default_rng(0)
    below = np.column_stack([rng.uniform(1.5, 3.4, 200), rng.uniform(0.2, 1.0, 200)])
    r = wall.cast_rays(below, np.full(200, 3 * np.pi / 4 - 0.3), 10.0)
    ends = below + r[:, None] * np.array([np.cos(3 * np.pi / 4 - 0.3), np.sin(3 * np.pi / 4 - 0.3)])
    assert np.all(ends[:, 1] - ends[:, 0] < 0.2)  # stopped at (or just past) the diagonal


def test_grid_rejects_bad_input():
    with pytest.raises(ValueError, match="resolution"):
        OccupancyGrid(np.zeros((3, 3), bool), 0.0)
    with pytest.raises(ValueError, match="bool"):
        OccupancyGrid(np.zeros((3, 3)), 0.1)
    with pytest.raises(ValueError, match="max_range"):
        room().cast_rays(np.zeros(2), 0.0, float("nan"))


# ------------------------------------------------------------------ resampling primitives
def test_low_variance_resampling_counts_are_within_one_of_expected():
    rng = np.random.default_rng(2)
    w = rng.random(500) ** 4
    w /= w.sum()
    for n in (100, 500, 2000):
        idx = low_variance_indices(w, n, rng)
        assert idx.size == n and np.all(np.diff(idx) >= 0)
        counts = np.bincount(idx, minlength=w.size)
        assert np.all(np.abs(counts - n * w) < 1.0 + 1e-9)
    with pytest.raises(ValueError, match="sum"):
        low_variance_indices(np.zeros(4), 4, rng)
    with pytest.raises(ValueError, match="sum"):
        low_variance_indices(np.array([0.5, np.nan]), 4, rng)


def test_kld_bound_matches_chi_square_quantile():
    eps, delta = 0.05, 0.01
    k = np.array([2, 5, 20, 100, 1000])
    exact = chi2.ppf(1 - delta, k - 1) / (2 * eps)
    np.testing.assert_allclose(kld_sample_bound(k, eps, delta), exact, rtol=0.02)
    assert kld_sample_bound(np.array([1]), eps, delta)[0] == 1


# ------------------------------------------------------------------ motion model
def test_noise_free_motion_follows_the_arc_and_reverses():
    g = room()
    cfg = MCLConfig(n_particles=5, motion=ParticleMotionNoise(0, 0, 0, 0, 0, 0))
    pf = ParticleFilter(g, np.random.default_rng(0), cfg)
    start = np.array([[2.0, 3.0, 0.5]] * 5)
    pf.set_particles(start)
    v, w, dt = 0.4, 0.8, 1.5
    pf.predict_odometry(v, w, dt)
    th = 0.5 + w * dt
    expected = [2.0 + v / w * (np.sin(th) - np.sin(0.5)), 3.0 - v / w * (np.cos(th) - np.cos(0.5))]
    np.testing.assert_allclose(pf.particles[:, :2], [expected] * 5, atol=1e-5)
    np.testing.assert_allclose(pf.particles[:, 2], wrap_angle(th), atol=1e-5)
    pf.predict_delta((-1.0, 0.0, 0.0))  # straight back, no half-turn
    np.testing.assert_allclose(pf.particles[:, 2], wrap_angle(th), atol=1e-5)
    assert pf.odometer == pytest.approx(v * dt * np.sinc(w * dt / 2 / np.pi) + 1.0, rel=1e-6)


def test_composed_odometry_equals_sequential_predictions():
    g = room()
    noise_free = MCLConfig(n_particles=3, motion=ParticleMotionNoise(0, 0, 0, 0, 0, 0))
    a = ParticleFilter(g, np.random.default_rng(0), noise_free)
    b = ParticleFilter(g, np.random.default_rng(0), noise_free)
    start = np.array([[2.0, 3.0, 0.5], [5.0, 1.0, -2.0], [7.0, 4.0, 3.0]])
    a.set_particles(start)
    b.set_particles(start)
    v = np.array([0.3, 0.5, 0.5, -0.2, 0.0])
    w = np.array([0.0, 0.4, -1.0, 0.3, 0.8])
    for vi, wi in zip(v, w, strict=True):
        a.predict_odometry(vi, wi, 0.1)
    b.predict_odometry_sequence(v, w, 0.1)
    np.testing.assert_allclose(a.particles, b.particles, atol=1e-5)
    assert compose_odometry(np.array([1.0]), np.array([0.0]), 2.0) == pytest.approx([2, 0, 0])


def test_motion_noise_grows_with_translation_and_rotation():
    g = room()
    noise = ParticleMotionNoise(min_xy=0.0, min_heading=0.0)
    pf = ParticleFilter(g, np.random.default_rng(3), MCLConfig(n_particles=4000, motion=noise))

    def spread_after(delta):
        pf.set_particles(np.tile([5.0, 3.0, 0.0], (4000, 1)))
        pf.predict_delta(delta)
        p = pf.particles
        return np.std(p[:, 0]), np.std(wrap_angle(p[:, 2]))

    sx_short, _ = spread_after((0.1, 0.0, 0.0))
    sx_long, _ = spread_after((1.0, 0.0, 0.0))
    _, sh_small = spread_after((0.0, 0.0, 0.1))
    _, sh_big = spread_after((0.0, 0.0, 1.5))
    assert sx_long == pytest.approx(noise.trans_trans * 1.0, rel=0.1)
    assert sx_short == pytest.approx(noise.trans_trans * 0.1, rel=0.1)
    assert sh_big == pytest.approx(noise.rot_rot * 1.5, rel=0.1)
    assert sh_small == pytest.approx(noise.rot_rot * 0.1, rel=0.1)


# ------------------------------------------------------------------ localization behaviour
def test_global_localization_converges_in_asymmetric_map():
    g = room()
    for seed in (0, 1, 2):
        pf = ParticleFilter(g, np.random.default_rng(seed), MCLConfig(n_particles=2000))
        robot = Robot(g, seed + 10)
        assert pf.particle_spread(robot.pose) > 2.0  # starts lost
        spread = run(pf, robot, steps=40)
        # bounded time: localized after 25 steps (5 s, ~2 m of driving) and staying so
        assert max(spread[25:]) < 0.5, spread
        est = pf.belief().mean
        assert np.hypot(*(est[:2] - robot.pose[:2])) < 0.2
        assert abs(wrap_angle(est[2] - robot.pose[2])) < 0.1


@pytest.mark.parametrize("random_fraction", [0.03, 0.0])
def test_kidnapped_robot_is_recovered(random_fraction):
    # 0.0: only the augmented-MCL slow/fast averages can trigger injection. Within 40
    # steps a kidnapped robot is found again in about 85 % of episodes (100 seeds of
    # this setup), otherwise its particles lock onto a similar-looking place: most of
    # these five fixed episodes recover (4 of 5 today, both fractions; at a rate of
    # 0.85, 3 or more of 5 fail to recover with probability 2.7 %). This drives the
    # filter's own resample_if_needed(); the env's schedule (resampling only when the
    # ESS falls) is tested in tests/env/test_mcl_env.py.
    g = room()
    cfg = MCLConfig(n_particles=2000, random_fraction=random_fraction)
    recovered = []
    for seed in range(5):
        pf = ParticleFilter(g, np.random.default_rng(seed), cfg)
        robot = Robot(g, seed + 1)
        spread = run(pf, robot, steps=40)
        assert spread[-1] < 0.3
        robot.pose = np.array([8.5, 4.0, 2.0])  # teleport, odometry does not notice
        robot.wp = 6
        assert pf.particle_spread(robot.pose) > 2.0
        spread = run(pf, robot, steps=40)
        recovered.append(max(spread[-10:]) < 0.5)
    assert sum(recovered) >= 3, recovered


def test_kidnap_triggers_injection_only_after_the_likelihood_drops():
    g = room()
    cfg = MCLConfig(n_particles=2000, random_fraction=0.0)
    pf = ParticleFilter(g, np.random.default_rng(7), cfg)
    robot = Robot(g, 8)
    run(pf, robot, steps=40)
    assert pf.inject_probability == 0.0  # tracking well: fast average >= slow average
    robot.pose = np.array([8.5, 4.0, 2.0])
    robot.wp = 6
    injected = []
    for _ in range(5):
        run(pf, robot, steps=1)
        injected.append(pf.inject_probability)
    assert max(injected) > 0.1


def test_adaptive_particle_count_shrinks_when_focused():
    g = room()
    cfg = MCLConfig(adaptive=True, n_particles=5000, n_min=200, n_max=5000)
    pf = ParticleFilter(g, np.random.default_rng(9), cfg)
    robot = Robot(g, 10)
    run(pf, robot, steps=1)
    assert pf.n_particles > 2000  # globally uncertain: many bins occupied
    spread = run(pf, robot, steps=30)
    # Focused and honest: the belief's position error passes the 99.9 % chi-square bound
    # of 2 dof (13.8; measured 0.65), and its particles lie closer to the truth than one
    # beam's std lf_sigma, 0.2 m (30 beams agree; measured mean distance 0.042 m).
    belief = pf.belief()
    err = belief.mean[:2] - robot.pose[:2]
    assert err @ np.linalg.solve(belief.cov[:2, :2], err) < chi2.ppf(0.999, 2)
    assert spread[-1] < cfg.lf_sigma
    assert 200 <= pf.n_particles < 600


@pytest.mark.parametrize("lookup_bins", [0, 180])
def test_beam_model_tracks_with_wide_cones(lookup_bins):
    g = room()
    beams = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    cfg = MCLConfig(n_particles=500, beam_lookup_bins=lookup_bins)
    pf = ParticleFilter(g, np.random.default_rng(11), cfg)
    robot = Robot(g, 12)
    pf.init_gaussian(robot.pose + [0.5, -0.4, 0.2], np.diag([0.5, 0.5, 0.3]) ** 2)
    assert pf.particle_spread(robot.pose) > 0.6
    err = []
    for _ in range(25):
        v, w, dt, _ = robot.step()
        pf.predict_odometry(v, w, dt)
        z = np.min(
            [g.simulate_scan(robot.pose, beams + off, MAX_RANGE) for off in (-0.09, 0.0, 0.09)],
            axis=0,
        )
        pf.update_beam(z + 0.05 * robot.rng.standard_normal(z.size), beams, MAX_RANGE,
                       cone_half_width=0.09)
        pf.resample_if_needed()
        err.append(pf.particle_spread(robot.pose))
    assert max(err[-5:]) < 0.3, err


def test_likelihood_field_matches_the_textbook_formula():
    g = room()
    cfg = MCLConfig(n_particles=400, lf_sigma=0.25, lf_z_hit=0.8, lf_z_rand=0.2)
    pf = ParticleFilter(g, np.random.default_rng(4), cfg)
    rng = np.random.default_rng(5)
    parts = np.column_stack([g.sample_free(400, rng), rng.uniform(-np.pi, np.pi, 400)])
    # in a wall, in a box, and just outside the map (particles farther out are clamped to
    # one cell outside the map, where they get the penalty)
    parts[:5, :2] = [[0.05, 3.0], [2.5, 2.3], [-0.05, 1.0], [10.08, 5.5], [4.0, 6.05]]
    pf.set_particles(parts)
    max_range = 30.0  # longer than the map's diagonal: long readings get clipped internally
    z = np.concatenate([rng.uniform(0.2, 6.0, 27), [25.0, 29.0, 30.0]])
    pf.update_likelihood_field(z, BEAMS, max_range)
    # reference: world endpoints, EDT of a generously padded map, clipped at lf_max_dist
    pad = 400
    dist = np.minimum(g.distance_field(pad), cfg.lf_max_dist)
    keep = z < max_range
    ang = parts[:, 2:3] + BEAMS[keep]
    ex = parts[:, 0:1] + z[keep] * np.cos(ang)
    ey = parts[:, 1:2] + z[keep] * np.sin(ang)
    ix = np.floor(ex / RES).astype(int) + pad
    iy = np.floor(ey / RES).astype(int) + pad
    d = dist[iy, ix]
    lik = cfg.lf_z_hit * np.exp(-0.5 * (d / cfg.lf_sigma) ** 2) / (
        cfg.lf_sigma * np.sqrt(2 * np.pi)) + cfg.lf_z_rand / max_range
    loglik = np.log(lik).sum(axis=1) + np.where(g.is_free(parts[:, :2]), 0.0, cfg.occupied_loglik)
    expected = np.exp(loglik - loglik.max())
    expected /= expected.sum()
    np.testing.assert_allclose(pf.weights, expected, rtol=1e-3, atol=1e-9)


def _lf_reference(g: OccupancyGrid, cfg: MCLConfig, parts: np.ndarray, z: np.ndarray,
                  beams: np.ndarray, max_range: float) -> np.ndarray:
    """Per-particle scan log-likelihood from the textbook formula, in float64."""
    pad = 400
    dist = np.minimum(g.distance_field(pad), cfg.lf_max_dist)
    keep = z < max_range
    ang = parts[:, 2:3] + beams[keep]
    ex = parts[:, 0:1] + z[keep] * np.cos(ang) - g.origin[0]
    ey = parts[:, 1:2] + z[keep] * np.sin(ang) - g.origin[1]
    d = dist[np.floor(ey / g.resolution).astype(int) + pad,
             np.floor(ex / g.resolution).astype(int) + pad]
    lik = cfg.lf_z_hit * np.exp(-0.5 * (d / cfg.lf_sigma) ** 2) / (
        cfg.lf_sigma * np.sqrt(2 * np.pi)) + cfg.lf_z_rand / max_range
    return cfg.likelihood_exponent * np.log(lik).sum(axis=1) + np.where(
        g.is_free(parts[:, :2]), 0.0, cfg.occupied_loglik)


@pytest.mark.parametrize("n_beams", [30, 90, 360])  # float32 exp, float64 exp, max subtracted
def test_likelihood_field_weights_and_evidence_match_float64(n_beams):
    g = room()
    cfg = MCLConfig(n_particles=300)
    rng = np.random.default_rng(8)
    beams = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    pose = np.array([5.0, 3.0, 0.4])
    z = g.simulate_scan(pose, beams, MAX_RANGE)
    pf = ParticleFilter(g, np.random.default_rng(9), cfg)
    pf.init_gaussian(pose, np.diag([0.4, 0.4, 0.2]) ** 2)
    for prior in ("non-uniform", "resampled"):
        if prior == "resampled":
            pf.resample()  # uniform weights: the update skips multiplying by them
        parts, w0 = pf.particles.copy(), pf.weights.copy()
        if prior == "non-uniform":
            w0 = rng.random(w0.size) + 0.1
            w0 /= w0.sum()
            pf.set_particles(parts, w0)
        evidence = pf.update_likelihood_field(z, beams, MAX_RANGE)
        ll = _lf_reference(g, cfg, parts, z, beams, MAX_RANGE)
        m = ll.max()
        expected = w0 * np.exp(ll - m)
        assert evidence == pytest.approx(m + np.log(expected.sum()), abs=1e-3)
        np.testing.assert_allclose(pf.weights, expected / expected.sum(), rtol=2e-3, atol=1e-12)


def test_endpoint_cells_are_float64_floors():
    # the float32 endpoint arithmetic picks the float64 cell for all but a few endpoints
    # lying within ~1e-5 cells of a cell boundary (weights then differ in one beam)
    for origin in ((0.0, 0.0), (500000.0, 4200000.0)):
        g0 = room()
        g = OccupancyGrid(g0.occupied, g0.resolution, origin)
        cfg = MCLConfig(n_particles=5000)
        rng = np.random.default_rng(11)
        parts = np.column_stack([rng.uniform(0.2, 9.8, 5000) + origin[0],
                                 rng.uniform(0.2, 5.8, 5000) + origin[1],
                                 rng.uniform(-np.pi, np.pi, 5000)])
        z = rng.uniform(0.1, MAX_RANGE - 0.1, BEAMS.size)
        pf = ParticleFilter(g, np.random.default_rng(0), cfg)
        pf.set_particles(parts)
        pf.update_likelihood_field(z, BEAMS, MAX_RANGE)
        parts = pf.particles  # float32 state: compare the endpoint arithmetic alone
        ll = _lf_reference(g, cfg, parts, z, BEAMS, MAX_RANGE)
        expected = np.exp(ll - ll.max())
        expected /= expected.sum()
        off = ~np.isclose(pf.weights, expected, rtol=1e-3, atol=1e-12)
        assert np.count_nonzero(off) <= 3


def test_low_variance_resampling_skips_zero_weights():
    rng = np.random.default_rng(4)
    w = rng.random(200) * (rng.random(200) < 0.3)
    w[0] = w[-1] = 0.0
    for n in (0, 1, 37, 200, 1000):
        for _ in range(20):
            idx = low_variance_indices(w, n, rng)
            assert idx.size == n and np.all(w[idx] > 0)


def test_headings_stay_wrapped_through_motion_updates_and_resampling():
    g = room()
    pf = ParticleFilter(g, np.random.default_rng(6), MCLConfig(n_particles=500))
    pf.init_gaussian(np.array([5.0, 3.0, 3.1]), np.diag([0.2, 0.2, 0.3]) ** 2)
    z = g.simulate_scan(np.array([5.0, 3.0, 3.1]), BEAMS, MAX_RANGE)
    for k in range(21):
        pf.predict_delta((0.05, 0.0, 0.7))
        h = pf.particles[:, 2]
        assert np.all((h >= -np.pi) & (h < np.pi))
        pf.update_likelihood_field(z, BEAMS, MAX_RANGE)
        if k % 3 == 0:
            pf.resample()


def test_pickled_and_copied_filters_continue_identically():
    import copy
    import pickle

    g = room()
    pf = ParticleFilter(g, np.random.default_rng(12), MCLConfig(n_particles=300))
    pf.init_gaussian(np.array([5.0, 3.0, 0.3]), np.diag([0.3, 0.3, 0.1]) ** 2)
    z = g.simulate_scan(np.array([5.0, 3.0, 0.3]), BEAMS, MAX_RANGE)
    for _ in range(3):  # fill the work-array caches
        pf.predict_delta((0.05, 0.0, 0.02))
        pf.update_likelihood_field(z, BEAMS, MAX_RANGE)
    clones = [pickle.loads(pickle.dumps(pf)), copy.deepcopy(pf)]
    for f in [pf, *clones]:
        for _ in range(3):
            f.resample_if_needed()
            f.predict_delta((0.05, 0.0, 0.02))
            f.update_likelihood_field(z, BEAMS, MAX_RANGE)
    for c in clones:
        np.testing.assert_array_equal(c.particles, pf.particles)
        np.testing.assert_array_equal(c.weights, pf.weights)


def test_map_far_from_the_origin_gives_the_same_weights():
    # real logs use UTM-size coordinates: float32 shortcuts must not lose precision there
    local = room()
    utm = OccupancyGrid(local.occupied, local.resolution, (500000.0, 4200000.0))
    pose = np.array([5.0, 3.0, 0.3])
    z = local.simulate_scan(pose, BEAMS, MAX_RANGE)
    weights = []
    for g in (local, utm):
        pf = ParticleFilter(g, np.random.default_rng(0), MCLConfig(n_particles=500))
        pf.init_gaussian(np.r_[pose[:2] + g.origin, pose[2]], np.diag([0.3, 0.3, 0.1]) ** 2)
        pf.update_likelihood_field(z, BEAMS, MAX_RANGE)
        weights.append(pf.weights.copy())
    assert weights[0].max() > 5 / 500  # the scan is informative
    np.testing.assert_allclose(weights[1], weights[0], atol=1e-6)


def test_filters_on_one_map_share_the_likelihood_table():
    g = room()
    a = ParticleFilter(g, np.random.default_rng(0), MCLConfig(n_particles=10))
    b = ParticleFilter(g, np.random.default_rng(1), MCLConfig(n_particles=10))
    c = ParticleFilter(g, np.random.default_rng(1), MCLConfig(n_particles=10, lf_sigma=0.5))
    assert a.lf_field(MAX_RANGE) is b.lf_field(MAX_RANGE)
    assert c.lf_field(MAX_RANGE) is not a.lf_field(MAX_RANGE)


def test_beam_model_prefers_the_true_pose_and_scores_max_range_readings():
    g = room()
    pf = ParticleFilter(g, np.random.default_rng(13), MCLConfig(n_particles=3))
    true = np.array([5.0, 2.5, 0.3])
    pf.set_particles(np.array([true, true + [0.5, 0.0, 0.0], true + [0.0, 0.0, 0.4]]))
    z = g.simulate_scan(true, BEAMS, MAX_RANGE)
    z[0] = MAX_RANGE  # a max-range reading must not produce zero or NaN weights
    pf.update_beam(z, BEAMS, MAX_RANGE)
    w = pf.weights
    assert np.all(np.isfinite(w)) and w[0] > 0.9 and w.sum() == pytest.approx(1.0)


def test_same_seed_same_particles():
    g = room()
    runs = []
    for _ in range(2):
        pf = ParticleFilter(g, np.random.default_rng(21), MCLConfig(n_particles=500))
        run(pf, Robot(g, 22), steps=5)
        runs.append((pf.particles.copy(), pf.weights.copy()))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


# ------------------------------------------------------------------ belief outputs
def test_belief_uses_circular_mean_and_wrapped_covariance():
    g = room()
    pf = ParticleFilter(g, np.random.default_rng(0), MCLConfig(n_particles=1000))
    rng = np.random.default_rng(1)
    parts = np.column_stack([
        rng.normal(3.0, 0.2, 1000), rng.normal(4.0, 0.1, 1000),
        wrap_angle(np.pi + rng.normal(0.0, 0.05, 1000)),
    ])
    pf.set_particles(parts)
    b = pf.belief()
    assert abs(wrap_angle(b.mean[2] - np.pi)) < 0.01
    np.testing.assert_allclose(np.sqrt(np.diag(b.cov)), [0.2, 0.1, 0.05], rtol=0.1)
    assert b.particles.shape == (1000, 3) and b.weights.sum() == pytest.approx(1.0)
    assert pf.particle_spread(np.array([3.0, 4.0, 0.0])) == pytest.approx(
        np.mean(np.hypot(parts[:, 0] - 3, parts[:, 1] - 4))
    )


def test_belief_features_fixed_size_and_informative():
    g = room()
    names = belief_feature_names()
    pf = ParticleFilter(g, np.random.default_rng(0), MCLConfig(n_particles=3000))
    lost = pf.belief_features()
    pf.init_gaussian(np.array([5.0, 3.0, 0.0]), np.diag([0.1, 0.1, 0.05]) ** 2, n=700)
    focused = pf.belief_features()
    for f in (lost, focused):
        assert f.shape == (len(names),) and f.dtype == np.float32 and np.all(np.isfinite(f))
        ix = {n: i for i, n in enumerate(names)}
        hist = f[ix["hist_r0_c0"]:ix["hist_outside"] + 1]
        heads = f[ix["heading_hist_0"]:]
        assert hist.sum() == pytest.approx(1.0, abs=1e-5)
        assert heads.sum() == pytest.approx(1.0, abs=1e-5)
    ix = {n: i for i, n in enumerate(names)}
    assert focused[ix["log10_std_x"]] < lost[ix["log10_std_x"]] - 1.0
    assert focused[ix["hist_entropy"]] < lost[ix["hist_entropy"]]
    assert focused[ix["hist_outside"]] < 0.01 < lost[ix["hist_outside"]]
    assert focused[ix["heading_resultant"]] > 0.99 > 0.1 > lost[ix["heading_resultant"]]
    # centre cell of the egocentric grid holds most of the focused mass
    assert focused[ix["hist_r2_c2"]] > 0.9
    assert focused[ix["x_norm"]] == pytest.approx(0.0, abs=0.02)
    assert len(pf.belief_features(hist_cells=3, heading_bins=4)) == len(belief_feature_names(3, 4))


@pytest.mark.parametrize("heading", [-2.9, -0.5, 0.2, 0.5])
def test_belief_features_of_a_collapsed_heading_stay_finite(heading):
    # float32 headings that all agree give a mean resultant a hair above 1
    pf = ParticleFilter(room(), np.random.default_rng(0), MCLConfig(n_particles=3000))
    pf.init_gaussian(np.array([5.0, 3.0, heading]), np.diag([0.1, 0.1, 1e-9]) ** 2, n=7)
    assert np.all(np.isfinite(pf.belief_features()))


def test_bad_inputs_raise_value_errors():
    g = room()
    pf = ParticleFilter(g, np.random.default_rng(0), MCLConfig(n_particles=50))
    with pytest.raises(ValueError, match="dt"):
        pf.predict_odometry(0.1, 0.0, -1.0)
    with pytest.raises(ValueError, match="finite"):
        pf.predict_odometry(float("nan"), 0.0, 0.1)
    with pytest.raises(ValueError, match="NaN"):
        pf.update_likelihood_field(np.array([1.0, np.nan]), np.zeros(2), 5.0)
    with pytest.raises(ValueError, match="match"):
        pf.update_likelihood_field(np.ones(3), np.zeros(2), 5.0)
    with pytest.raises(ValueError, match="max_range"):
        pf.update_beam(np.ones(2), np.zeros(2), 0.0)
    with pytest.raises(ValueError, match="factors"):
        pf.apply_weight_factors(np.full(50, np.inf))
    with pytest.raises(ValueError, match="n_min"):
        MCLConfig(n_min=10, n_max=5)


def test_weights_stay_finite_under_hopeless_scans_and_out_of_map_particles():
    g = room()
    pf = ParticleFilter(g, np.random.default_rng(0), MCLConfig(n_particles=200))
    parts = np.column_stack([np.linspace(-50, 60, 200), np.linspace(-40, 40, 200), np.zeros(200)])
    pf.set_particles(parts)
    for _ in range(50):  # each update multiplies in ~1e-30; weights must never underflow to NaN
        pf.update_likelihood_field(np.full(30, 0.01), BEAMS, MAX_RANGE)
    assert np.all(np.isfinite(pf.weights)) and pf.weights.sum() == pytest.approx(1.0)
    inside = g.is_free(parts[:, :2])
    assert pf.weights[inside].sum() > 0.99  # particles off the map are penalized
    pf.update_likelihood_field(np.full(30, np.inf), BEAMS, MAX_RANGE)  # all max range: no beams
    assert np.all(np.isfinite(pf.weights))
    pf.resample()
    assert pf.n_particles == 200


def test_position_std_is_the_rms_weighted_axis_std():
    pf = ParticleFilter(room(), np.random.default_rng(3), MCLConfig(n_particles=500))
    pf.set_particles(pf.particles, np.random.default_rng(4).random(500))
    w, xy = pf.weights, pf.particles[:, :2]
    var = w @ (xy - w @ xy) ** 2
    assert pf.position_std() == pytest.approx(np.sqrt(var.mean()), rel=1e-9)
    pf.init_gaussian(np.array([5.0, 3.0, 0.0]), np.diag([0.0, 0.0, 0.1]))
    assert pf.position_std() < 1e-5  # float32 state rounding only


def test_default_filter_spreads_1000_particles():
    """A filter built without a config starts global localization with 1000 particles,
    equally weighted, all in free space, and keeps 1000 through resampling."""
    g = room()
    pf = ParticleFilter(g, np.random.default_rng(0))
    assert pf.n_particles == 1000 and pf.ess == pytest.approx(1000.0)
    assert g.is_free(pf.particles[:, :2]).all()
    pf.resample()
    assert pf.n_particles == 1000


@pytest.mark.parametrize(("heavy", "resampled"), [(480, True), (520, False)])
def test_resampling_starts_below_half_the_particles(heavy, resampled):
    """Equal weight on ``heavy`` of 1000 particles (effective sample size ``heavy``): the
    default filter resamples below 500 and not above (no injection to force it)."""
    pf = ParticleFilter(room(), np.random.default_rng(0),
                        MCLConfig(augmented=False, random_fraction=0.0))
    pf.set_particles(pf.particles, (np.arange(1000) < heavy).astype(float))
    assert pf.ess == pytest.approx(heavy)
    assert pf.resample_if_needed() is resampled
    assert pf.ess == pytest.approx(1000.0 if resampled else heavy)


def test_resampling_injects_three_percent_uniform_particles():
    """A fresh filter (no likelihood history) injects ``random_fraction`` of uniform
    particles at each resampling: of 100 000 particles at one pose, a binomial(100 000,
    0.03) count lands elsewhere, within its two-sided 99.9 % band (2824-3179; a 10 %
    change of the fraction moves the mean by 300)."""
    n = 100_000
    pf = ParticleFilter(room(), np.random.default_rng(4), MCLConfig(n_particles=n))
    pose = np.array([5.0, 3.0, 0.5])
    pf.set_particles(np.tile(pose, (n, 1)))
    pf.resample()
    moved = np.count_nonzero(np.abs(pf.particles - pose).max(axis=1) > 1e-4)
    lo, hi = binom.ppf(0.0005, n, 0.03), binom.isf(0.0005, n, 0.03)
    assert lo <= moved <= hi, (moved, lo, hi)
