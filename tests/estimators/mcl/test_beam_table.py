"""Tests of the per-map range and beam-likelihood tables and of the batched team updates."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.backends.mcl import known_map, map_resolution
from estimators.mcl.batch import (
    belief_summaries,
    compose_odometry_batch,
    particle_spreads,
    update_beam_batch,
)
from estimators.mcl.beam_table import (
    beam_lut,
    beam_probability,
    range_table,
    scan_loglik,
    table_error,
)
from estimators.mcl.filter import MCLConfig, ParticleFilter, compose_odometry
from estimators.mcl.occupancy import OccupancyGrid


def hallway_map() -> tuple[OccupancyGrid, float, float]:
    """The sonar map of ``symmetric_hallway``, its max range and its beams' cone half width."""
    env = coop_loc_env.parallel_env("symmetric_hallway")
    cfg = env.unwrapped.config
    grid = known_map(env.unwrapped.world, "sonar", map_resolution(cfg))
    return grid, cfg.sonar_max_range, 0.5 * np.deg2rad(cfg.sonar_fov_deg) / cfg.sonar_beams


def small_map() -> OccupancyGrid:
    return OccupancyGrid.from_shapes((8.0, 6.0), 0.2, circles=[((3.0, 3.0), 0.5)],
                                     polygons=[np.array([[5.0, 1.0], [6.5, 1.5], [5.5, 2.5]])],
                                     border=True)


def test_table_matches_exact_ray_casts_within_the_beam_noise():
    grid, max_range, cone = hallway_map()
    table = range_table(grid, max_range, 256, cone, 3)
    err = table_error(grid, table, n=20000, seed=0)
    # Most lookups are exact (same wall face as from the cell centre); the tail comes
    # from rays that pass a corner on the other side than the centre's ray does.
    assert np.median(err) < 0.001
    assert np.percentile(err, 90) < 0.01
    # below the simulated sonar's range noise (0.15 m std); 0.14 m with these poses
    assert np.percentile(err, 99) < 0.15
    # the first-order corrections are what make it so: cell-centre ranges alone are worse
    plain = table._replace(scales=table.scales * np.array([1, 0, 0, 0], dtype=np.float32))
    err_plain = table_error(grid, plain, n=20000, seed=0)
    assert np.percentile(err_plain, 90) > 30 * np.percentile(err, 90)
    assert np.percentile(err_plain, 99) > 3 * np.percentile(err, 99)


def test_tables_are_shared_by_equal_maps():
    a, b = small_map(), small_map()
    assert a is not b
    t = range_table(a, 5.0, 64)
    assert range_table(b, 5.0, 64) is t  # a new episode on the same layout builds nothing
    assert range_table(b, 5.0, 64, 0.2, 3) is not t
    other = OccupancyGrid.from_shapes((8.0, 6.0), 0.2, border=True)
    assert range_table(other, 5.0, 64) is not t
    pf = ParticleFilter(b, np.random.default_rng(0), MCLConfig(n_particles=10,
                                                               beam_lookup_bins=64))
    assert pf.beam_tables(5.0)[0] is t


def test_outside_and_occupied_positions_read_zero_range():
    grid = small_map()
    table = range_table(grid, 5.0, 64)
    x = np.array([-1.0, 100.0, 3.0 - 0.1], dtype=np.float32)  # outside, outside, in the disc
    y = np.array([1.0, 1.0, 3.0 - 0.1], dtype=np.float32)
    r = table.expected(x, y, np.zeros(3, dtype=np.float32), np.array([0.0, 1.0]))
    np.testing.assert_array_equal(r, 0.0)
    assert not table.free(x, y).any()


def test_likelihood_table_matches_the_beam_formula():
    max_range, sigma = 6.0, 0.5
    terms = dict(z_hit=0.7, z_short=0.1, z_max=0.1, z_rand=0.1, lambda_short=0.5)
    lut = beam_lut(max_range, sigma, exponent=1.0, **terms)
    rng = np.random.default_rng(0)
    z = rng.uniform(0, max_range * 0.99, 400)
    zexp = rng.uniform(0, max_range, (400, 1)).astype(np.float32)
    exact = np.log(beam_probability(z[None, :1], zexp, max_range, sigma, **terms))[:, 0]
    got = lut.loglik(zexp, lut.rows(z[:1]))
    # ranges are quantized to max_range / 511 (1.2 cm): far below sigma
    assert np.max(np.abs(got - exact)) < 0.05
    # a max-range reading scores the max-range term; a missing one scores nothing
    z_special = np.array([max_range + 1.0, np.nan])
    got = lut.loglik(np.full((1, 2), 2.0, dtype=np.float32), lut.rows(z_special))
    assert got[0] == pytest.approx(np.log(terms["z_max"] + terms["z_rand"] / max_range),
                                   rel=1e-6)


def team(n_filters: int = 3, seed: int = 0) -> list[ParticleFilter]:
    grid = small_map()
    cfg = MCLConfig(n_particles=400, beam_lookup_bins=128, adaptive=True, n_max=400)
    filters = [ParticleFilter(grid, np.random.default_rng(seed + i), cfg)
               for i in range(n_filters)]
    if n_filters > 1:
        filters[1].init_uniform(700)  # particle counts differ
    filters[-1].init_gaussian(np.array([2.0, 2.0, np.pi - 0.01]), np.diag([0.3, 0.3, 0.2]) ** 2)
    return filters


def test_batched_beam_update_equals_robot_by_robot_updates():
    filters = team()
    angles = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    rng = np.random.default_rng(5)
    ranges = rng.uniform(0.0, 6.5, (3, 12))
    ranges[0, 3] = np.nan  # a missing reading
    ranges[1, 5] = np.inf
    alone = copy.deepcopy(filters)
    evidence = update_beam_batch(filters, ranges, angles, 6.0, cone_half_width=0.2)
    for r, pf in enumerate(alone):
        ok = np.isfinite(ranges[r])
        ev = pf.update_beam(ranges[r][ok], angles[ok], 6.0, cone_half_width=0.2)
        # the same posterior, bit for bit (no randomness is involved in a measurement update)
        np.testing.assert_array_equal(pf.weights, filters[r].weights)
        assert ev == evidence[r]
        assert pf.w_slow == filters[r].w_slow and pf.w_fast == filters[r].w_fast
    # and the random streams stay the filters' own: resampling afterwards agrees too
    for pf, other in zip(alone, filters, strict=True):
        pf.resample()
        other.resample()
        np.testing.assert_array_equal(pf.particles, other.particles)


def test_batched_update_rejects_mixed_maps_and_bad_scans():
    filters = team(2)
    other = ParticleFilter(OccupancyGrid.from_shapes((8.0, 6.0), 0.2, border=True),
                           np.random.default_rng(0), filters[0].config)
    angles = np.zeros(2)
    with pytest.raises(ValueError, match="one map"):
        update_beam_batch([filters[0], other], np.ones((2, 2)), angles, 5.0)
    with pytest.raises(ValueError, match="shape"):
        update_beam_batch(filters, np.ones((3, 2)), angles, 5.0)
    with pytest.raises(ValueError, match=">= 0"):
        update_beam_batch(filters, -np.ones((2, 2)), angles, 5.0)


def test_belief_summaries_match_each_filter():
    filters = team()
    means, covs, feats = belief_summaries(filters)
    for r, pf in enumerate(filters):
        np.testing.assert_allclose(means[r], pf.mean_pose(), atol=1e-6)
        np.testing.assert_allclose(covs[r], pf.belief().cov, atol=1e-6)
        np.testing.assert_allclose(feats[r], pf.belief_features(), atol=1e-5)
    truth = np.array([[2.0, 2.0], [4.0, 3.0], [1.0, 1.0]])
    np.testing.assert_allclose(particle_spreads(filters, truth),
                               [pf.particle_spread(t) for pf, t in zip(filters, truth,
                                                                       strict=True)],
                               rtol=1e-6)


def test_batched_odometry_composition_matches_one_robot_at_a_time():
    rng = np.random.default_rng(2)
    v, w = rng.normal(size=(4, 5)), rng.normal(size=(4, 5))
    w[1] = 0.0  # straight driving
    got = compose_odometry_batch(v, w, 0.1)
    np.testing.assert_allclose(got, [compose_odometry(v[i], w[i], 0.1) for i in range(4)],
                               atol=1e-12)


def test_position_and_heading_fix_matches_the_gaussian_factors():
    pf = team(1)[0]
    ref = copy.deepcopy(pf)
    pf.update_fix(np.array([2.0, 3.0]), 0.5, heading=3.1, heading_std=0.2)
    parts = ref.particles
    d = parts[:, :2] - [2.0, 3.0]
    e = (parts[:, 2] - 3.1 + np.pi) % (2 * np.pi) - np.pi
    ref.apply_weight_factors(np.exp(-0.5 * (d * d).sum(axis=1) / 0.5) + 1e-12)
    ref.apply_weight_factors(np.exp(-0.5 * (e / 0.2) ** 2) + 1e-12)
    np.testing.assert_allclose(pf.weights, ref.weights, rtol=1e-4, atol=1e-12)
    with pytest.raises(ValueError, match="xy_var"):
        pf.update_fix(np.zeros(2), 0.0)


def test_compiled_scan_likelihood_repeats_the_table_lookups():
    grid = small_map()
    table = range_table(grid, 4.0, 60, 0.15, 3)  # not a power of two: modulo path
    lut = beam_lut(4.0, 0.3, 0.7, 0.1, 0.1, 0.1, 0.5, 0.2)
    rng = np.random.default_rng(4)
    n = 3000
    # inside, near and outside the map; headings far from [-pi, pi) as well
    st = np.stack([rng.uniform(-1.0, 9.0, n), rng.uniform(-1.0, 7.0, n),
                   rng.uniform(-9.0, 9.0, n)]).astype(np.float32)
    angles = np.linspace(-np.pi, np.pi, 9, endpoint=False)
    z = rng.uniform(0, 4.5, (2, 9))
    z[1, 2] = np.nan
    rows = lut.rows(z)
    ends = np.array([1000, n])
    flat = np.concatenate([st[:, :1000].ravel(), st[:, 1000:].ravel()])  # block layout
    got = scan_loglik(table, lut, flat, angles, rows, ends, -10.0)
    per_particle_rows = np.repeat(rows, [1000, n - 1000], axis=0)
    ref = lut.loglik(table.expected(st[0], st[1], st[2], angles), per_particle_rows)
    ref += np.where(table.free(st[0], st[1]), 0.0, -10.0)
    np.testing.assert_array_equal(got, ref)
