"""The compiled team passes of the particle filter against numpy references and against
the same filters updated one by one."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from estimators.geometry import wrap_angle
from estimators.mcl._team_kernels import lf_scan_rows
from estimators.mcl.batch import predict_batch, weigh_batch
from estimators.mcl.filter import MCLConfig, ParticleFilter
from estimators.mcl.likelihood_field import LF_POWER, beam_units, lf_endpoints, lf_loglik
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.sampling import kld_need, low_variance_from_cumulative, resample_team
from estimators.mcl.team import ParticleTeam
from estimators.mcl.weighting import weigh_team

BEAMS = np.linspace(-np.pi, np.pi, 20, endpoint=False)


def field_map() -> OccupancyGrid:
    return OccupancyGrid.from_shapes((9.0, 6.0), 0.1, circles=[((3.0, 3.0), 0.6)],
                                     polygons=[np.array([[6.0, 1.0], [7.5, 1.5], [6.5, 2.5]])],
                                     border=True)


def laser_team(cfg: MCLConfig | None = None) -> list[ParticleFilter]:
    grid = field_map()
    cfg = cfg or MCLConfig(n_particles=500)
    filters = [ParticleFilter(grid, np.random.default_rng(10 + i), cfg) for i in range(3)]
    filters[1].init_uniform(800)  # counts differ
    filters[2].init_gaussian(np.array([2.0, 2.0, 3.1]), np.diag([0.4, 0.4, 0.3]) ** 2)
    return filters


def test_compiled_field_scores_repeat_the_numpy_lookups():
    grid = field_map()
    pf = ParticleFilter(grid, np.random.default_rng(0), MCLConfig(n_particles=3000))
    rng = np.random.default_rng(1)
    # inside, near and outside the map; headings far from [-pi, pi) as well
    poses = np.column_stack([rng.uniform(-2.0, 11.0, 3000), rng.uniform(-2.0, 8.0, 3000),
                             rng.uniform(-3.0, 3.0, 3000)])
    pf.set_particles(poses)
    pf.particle_set.state[2] *= 3.0
    ranges = rng.uniform(0.1, 7.0, BEAMS.size)
    lf = pf.lf_field(8.0)
    bufs: dict = {}
    numpy_sum = lf_loglik(lf, pf.particle_set.state, ranges, BEAMS, {}, bufs).astype(np.float64)
    gathered = next(iter(bufs.values()))[7]  # (beams + 1, n): the field at each endpoint,
    acc = gathered[-1].copy()  # then the penalty at the particle's own cell
    for row in gathered[:-1]:  # summed in the compiled pass's order
        acc += row
    ref = LF_POWER * acc.astype(np.float64)
    np.testing.assert_allclose(ref, LF_POWER * numpy_sum, rtol=1e-6)  # BLAS sums in its order
    ux, uy = lf_endpoints(lf, ranges, BEAMS)
    n = pf.n_particles
    w_prev = rng.random(n)
    w_prev /= w_prev.sum()
    loglik = np.empty(n)
    ev = weigh_team(ParticleTeam.alone(pf), w_prev, np.zeros((1, 7)),
                    np.array([BEAMS.size]), loglik, False, np.zeros(1), np.ones(1),
                    pf.lf_kernel_args(8.0), ux[None], uy[None], float(LF_POWER))
    np.testing.assert_array_equal(loglik, ref)  # the same cells and float32 sums, bit for bit
    w = w_prev * np.exp(ref - ref.max())
    np.testing.assert_allclose(pf.weights, w / w.sum(), rtol=1e-12, atol=1e-300)
    assert math.isclose(ev[0], ref.max() + np.log(w.sum()), rel_tol=1e-12)


def test_compiled_scan_rows_round_as_the_numpy_endpoints():
    pf = ParticleFilter(field_map(), np.random.default_rng(0), MCLConfig(n_particles=10))
    lf = pf.lf_field(8.0)
    rng = np.random.default_rng(2)
    ranges = rng.uniform(0.0, 30.0, (4, BEAMS.size))  # some beyond the field's reach
    ranges[1, :5] = np.inf
    ranges[2] = np.nan  # no scan
    ranges[3, 3] = 8.0  # at the maximum range: no endpoint
    ux, uy, nb, k = lf_scan_rows(ranges, *beam_units(lf, BEAMS), lf.reach, 8.0)
    ok = ranges < 8.0
    ref_x, ref_y = lf_endpoints(lf, np.where(ok, ranges, np.nan), BEAMS)
    np.testing.assert_array_equal(ux, ref_x)  # NaN where no endpoint, bit for bit elsewhere
    np.testing.assert_array_equal(uy, ref_y)
    np.testing.assert_array_equal(k, ok.sum(axis=1))
    np.testing.assert_array_equal(nb, [k[0], k[1], -1, k[3]])


def test_team_step_equals_robot_by_robot_steps():
    filters = laser_team()
    alone = copy.deepcopy(filters)
    rng = np.random.default_rng(3)
    deltas = rng.normal(0.0, 0.2, (3, 3))
    ranges = rng.uniform(0.2, 9.0, (3, BEAMS.size))
    ranges[0, 4] = np.inf  # no endpoint
    ranges[2] = np.nan  # no scan at all for robot 2
    fixes = [None, ((4.0, 3.0), 0.5, 0.3, 0.05), ((2.0, 2.0), 0.2, None, 1.0)]
    for step in range(3):
        predict_batch(filters, deltas)
        for pf, d in zip(alone, deltas, strict=True):
            pf.predict_delta(d)
        for pf, other in zip(alone, filters, strict=True):
            # same draws, same motion
            np.testing.assert_array_equal(pf.particle_set.state, other.particle_set.state)
        rows = np.stack([f.fix_row(*fx) if fx else f.fix_row()
                         for f, fx in zip(filters, fixes, strict=True)])
        ev = weigh_batch(filters, ranges, BEAMS, 8.0, rows)
        for r, pf in enumerate(alone):
            if r < 2:
                ok = np.isfinite(ranges[r])
                assert ev[r] == pf.update_likelihood_field(ranges[r][ok], BEAMS[ok], 8.0)
            else:
                assert np.isnan(ev[r])
            if fixes[r]:
                pf.update_fix(*fixes[r])
            # the fixes multiply before, not after, normalizing: equal up to rounding
            np.testing.assert_allclose(pf.weights, filters[r].weights, rtol=1e-12, atol=1e-300)
            assert pf.w_slow == filters[r].w_slow and pf.w_fast == filters[r].w_fast
            # continue from identical weights
            filters[r].particle_set.weights = pf.particle_set.weights.copy()
        which = [True, step != 1, True]
        team = ParticleTeam.gather(filters)
        resample_team(team, team.weights(), which)
        for pf, again in zip(alone, which, strict=True):
            if again:
                pf.resample()
        for pf, other in zip(alone, filters, strict=True):
            np.testing.assert_array_equal(pf.particles, other.particles)
            np.testing.assert_array_equal(pf.weights, other.weights)


def reference_resample(pf: ParticleFilter) -> np.ndarray:
    """The resampling algorithm in plain numpy: ``(3, n)`` new state (poses from the centre of
    map cell (0, 0))."""
    cfg = pf.config
    rng = pf.rng
    p_inj = pf.inject_probability
    st = pf.particles.T - pf.particle_set.origin
    cum = np.add.accumulate(pf.weights)
    if cfg.adaptive:
        idx = low_variance_from_cumulative(cum, cfg.n_max, rng)
        words = rng.bit_generator.random_raw(cfg.n_max)
        for i in range(cfg.n_max):  # Fisher-Yates forward from the words' top 53 bits
            j = i + int(float(int(words[i]) >> 11) / 2.0**53 * (cfg.n_max - i))
            idx[i], idx[j] = idx[j], idx[i]
        sel = st[:, idx].astype(np.float32)
        bx, by, bt = cfg.kld_bin
        n_t = math.ceil(2 * math.pi / bt)
        kx = np.floor((sel[0].astype(float) + pf.particle_set.origin[0, 0]) / bx).astype(np.int64)
        ky = np.floor((sel[1].astype(float) + pf.particle_set.origin[1, 0]) / by).astype(np.int64)
        kt = np.clip(np.floor((sel[2] + np.float32(np.pi)) * np.float32(1 / bt)), 0, n_t - 1)
        key = ((kx - kx.min()) * (ky.max() - ky.min() + 1) + ky - ky.min()) * n_t + kt
        _, first = np.unique(key, return_index=True)
        new = np.zeros(key.size, dtype=bool)
        new[first] = True
        need = kld_need(cfg.kld_epsilon, cfg.kld_delta, cfg.n_min, cfg.n_max)[np.cumsum(new)]
        enough = np.flatnonzero(np.arange(1, cfg.n_max + 1) >= need)
        n = int(np.clip(enough[0] + 1 if enough.size else cfg.n_max, cfg.n_min, cfg.n_max))
        n_inj = int(rng.binomial(n, p_inj)) if p_inj > 0 else 0
        kept = sel[:, : n - n_inj]
    else:
        n = pf.n_particles
        n_inj = int(rng.binomial(n, p_inj)) if p_inj > 0 else 0
        kept = st[:, low_variance_from_cumulative(cum, n - n_inj, rng)].astype(np.float32)
    xy = pf.grid.sample_free(n_inj, rng)
    th = rng.uniform(-np.pi, np.pi, n_inj)
    org = pf.particle_set.origin
    injected = np.vstack([xy.T - org[:2], wrap_angle(th)[None]]).astype(np.float32)
    return np.concatenate([kept, injected], axis=1)


def test_resampling_repeats_the_numpy_algorithm():
    grid = field_map()
    for cfg in (MCLConfig(n_particles=600, adaptive=True, n_max=3000, n_min=50),
                MCLConfig(n_particles=600)):
        for seed in range(4):
            pf = ParticleFilter(grid, np.random.default_rng(seed), cfg)
            if seed in (1, 2):  # a compact belief: KLD-sampling keeps far fewer than n_max
                pf.init_gaussian(np.array([4.0, 4.0, 1.0]), np.diag([0.3, 0.3, 0.2]) ** 2)
            elif seed == 3:  # spread over kilometres: too many bins for a marker array
                pf.init_gaussian(np.array([4.0, 4.0, 1.0]), np.diag([3000.0, 20.0, 1.0]) ** 2)
            w = np.random.default_rng(seed + 7).random(pf.n_particles) ** 4
            pf.set_particles(pf.particles, w)
            pf.w_slow, pf.w_fast = 1.0, 0.7  # random particles are injected
            ref = copy.deepcopy(pf)
            expected = reference_resample(ref)
            pf.resample()
            np.testing.assert_array_equal(pf.particle_set.state, expected)
            assert pf.n_particles == expected.shape[1]
            if cfg.adaptive and seed in (1, 2):
                assert pf.n_particles < cfg.n_max // 2
            assert ref.rng.random() == pf.rng.random()  # the same number of draws


def test_ziggurat_normals_are_standard_normal():
    from scipy import stats

    from estimators.mcl.sampling import standard_normals

    rng = np.random.default_rng(0)
    z = np.concatenate([standard_normals(rng, np.empty(n, dtype=np.float32))
                        for n in (1, 7, 3000, 400_000)]).astype(float)
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.005
    assert stats.kstest(z, "norm").pvalue > 0.01
    # the tail beyond the base strip (3.44) and the wedges have the right mass
    assert np.mean(np.abs(z) > 3.442619855899) == pytest.approx(5.76e-4, rel=0.2)
    assert np.mean(np.abs(z) > 2.0) == pytest.approx(2 * stats.norm.sf(2.0), rel=0.03)
    # the same generator state gives the same normals
    a = standard_normals(np.random.default_rng(3), np.empty(500, dtype=np.float32))
    b = standard_normals(np.random.default_rng(3), np.empty(500, dtype=np.float32))
    np.testing.assert_array_equal(a, b)
