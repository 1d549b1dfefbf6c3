"""The compiled passes of the symmetric-copy keeper give bit for bit what the numpy code
they replace gives (main modes, copies topped up, scans scored along trajectories)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import coop_loc_env
from estimators.mcl._keeper_kernels import (
    SAFE,
    disc_weight_bound,
    pairwise_sum,
    weighted_median,
)
from estimators.mcl.beam_table import BeamLUT, RangeTable
from estimators.mcl.copy_keeper import filter_mode, mode_weight_below, top_up_copies
from estimators.mcl.copy_weights import TOP_MODE_HEADING_TOL, near_pose, top_mode
from estimators.mcl.detection_consistency import main_mode, scan_loglik_along, widen
from estimators.mcl.map_symmetry import symmetric_copies

TRUE = np.array([10.0, 1.25, 0.3])  # bottom corridor of the hallway ring


@pytest.fixture(scope="module")
def hallway():
    """The hallway's MCL backend after a reset (its grid, symmetries and beam tables)."""
    env = coop_loc_env.parallel_env("active_hallway", n_robots=1, cooperative_updates=False,
                                    start_poses=(tuple(TRUE),))
    env.reset(seed=0)
    return env.backends[0]


def _sorted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The weighted median as a sort finds it (the first sorted value whose running
    weight reaches half the total)."""
    order = np.argsort(x)
    cum = np.cumsum(w[order])
    return float(x[order[min(int(np.searchsorted(cum, 0.5 * cum[-1])), len(x) - 1)]])


def test_pairwise_sum_is_numpys_sum_bit_for_bit():
    rng = np.random.default_rng(0)
    for n in [*range(1, 300), 1000, 2047, 4096, 5003, 8192, 8193, 20000]:
        a = rng.random(n) ** 4
        assert pairwise_sum(a) == a.sum(), n


def test_weighted_median_matches_the_sorted_one():
    rng = np.random.default_rng(1)
    answered = 0
    for t in range(600):
        n = int(rng.integers(1, 2500))
        x = rng.normal(0.0, 5.0, n)
        if t % 3 == 0:
            x = np.round(x, 1)  # ties
        w = rng.random(n) ** 3
        w /= w.sum()
        value, ok = weighted_median(x, w)
        if ok:
            answered += 1
            assert value == _sorted_median(x, w)
    assert answered >= 590  # random weights almost never put half the weight at a boundary


def test_weighted_median_leaves_rounding_close_cases_to_the_sort():
    # half the weight lies ``d`` inside the middle value's share: decided here only when
    # ``d`` exceeds the margin, where no order of summation can move the crossing
    x = np.array([0.0, 1.0, 2.0])
    for d, ok_expected in ((1.1 * SAFE, True), (0.9 * SAFE, False)):
        w = np.array([0.5 - d, 2 * d, 0.5 - d])
        value, ok = weighted_median(x, w)
        assert ok is ok_expected
        if ok:
            assert value == _sorted_median(x, w) == 1.0
    # equal weights over an even count: the half falls on a boundary
    assert not weighted_median(np.arange(10.0), np.full(10, 0.1))[1]
    assert not weighted_median(np.array([0.0, np.nan]), np.full(2, 0.5))[1]
    assert not weighted_median(np.arange(3.0), np.array([0.6, -0.1, 0.5]))[1]


def _belief(rng: np.random.Generator, grid, spread: float, copies: dict) -> tuple:
    """Particles: a main cloud about ``TRUE`` (``spread`` m), ``copies`` {turn index:
    particle count} of it turned about the ring's centre, the rest uniform over the free
    space; random weights."""
    n = int(rng.integers(300, 2000))
    parts = np.empty((n, 3))
    parts[:, :2] = grid.sample_free(n, rng)
    parts[:, 2] = rng.uniform(-np.pi, np.pi, n)
    main = int(0.85 * n)
    parts[:main] = TRUE + rng.normal(0.0, [spread, spread, 0.1], (main, 3))
    start = main
    for turn, count in copies.items():
        count = min(count, n - start)
        a = turn * math.pi / 2
        c, s = math.cos(a), math.sin(a)
        d = parts[:count, :2] - 10.0
        parts[start:start + count, 0] = 10.0 + c * d[:, 0] - s * d[:, 1]
        parts[start:start + count, 1] = 10.0 + s * d[:, 0] + c * d[:, 1]
        start += count
    parts[:, 2] = (parts[:, 2] + np.pi) % (2 * np.pi) - np.pi
    w = rng.random(n) + 0.05
    return parts, w / w.sum()


def _widen_each(parts, w, cloud, syms, mass, radius, rng, grid):
    """The keeper's loop as numpy code: ``widen`` on each free turned copy in turn."""
    placed = False
    for sym in syms:
        turned = symmetric_copies(cloud, sym)
        turned = turned[grid.is_free(turned[:, :2])]
        if len(turned):
            parts, w, k = widen(parts, w, turned, mass, radius, rng)
            placed = placed or k > 0
    return parts, w, placed


def test_filter_mode_is_main_mode_bit_for_bit(hallway):
    rng = np.random.default_rng(2)
    pf = hallway.filters[0]
    for t in range(60):
        spread = (0.05, 0.3, 1.5, 4.0)[t % 4]  # mean and median branches
        parts, w = _belief(rng, pf.grid, spread, {2: int(rng.integers(0, 200))})
        pf.set_particles(parts, w)
        mask, mass = filter_mode(pf.particle_set, 2.0)
        _, expected = main_mode(pf.particles[:, :2], pf.weights, 2.0)
        assert np.array_equal(mask, expected)
        assert mass == float(pf.weights[expected].sum())


def test_the_disc_bound_holds_and_settles_spread_beliefs(hallway):
    rng = np.random.default_rng(5)
    pf = hallway.filters[0]
    settled = 0
    for t in range(60):
        spread = (0.3, 1.0, 2.0, 6.0)[t % 4]
        parts, w = _belief(rng, pf.grid, spread, {})
        pf.set_particles(parts, w)
        ps = pf.particle_set
        _, mass = filter_mode(ps, 2.0)
        bound = disc_weight_bound(ps.state, *ps.origin_xy, ps.weights, 2.0)
        assert bound >= mass
        # every disc of the radius, centred on particles, holds no more than the bound
        xy = pf.particles[:, :2]
        for c in xy[rng.integers(0, len(xy), 20)]:
            assert pf.weights[((xy - c) ** 2).sum(axis=1) <= 4.0].sum() <= bound + 1e-12
        if mode_weight_below(ps, 2.0, 0.8):
            settled += 1
            assert mass < 0.8
    assert settled >= 10  # the widest beliefs are settled without their mode


def test_top_up_copies_is_widen_copy_by_copy(hallway):
    grid = hallway.filters[0].grid
    syms = hallway.symmetries["sonar"]
    rng = np.random.default_rng(3)
    placed_any = held_any = 0
    for t in range(60):
        mass = (0.005, 0.05)[t % 2]
        spread = (0.05, 0.4, 0.8)[t % 3]
        # copies with many particles (holding their share), few, or none
        copies = {k: int(rng.choice([0, 3, 40, 300])) for k in (1, 2, 3)}
        parts, w = _belief(rng, grid, spread, copies)
        _, mode = main_mode(parts[:, :2], w, 2.0)
        cloud = parts[mode]
        seed = int(rng.integers(2**32))
        rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
        got = top_up_copies(parts, w, cloud, syms, mass, 2.0, rng_a, grid)
        want = _widen_each(parts, w, cloud, syms, mass, 2.0, rng_b, grid)
        assert np.array_equal(got[0], want[0])
        assert np.array_equal(got[1], want[1])
        assert got[2] == want[2]
        assert rng_a.bit_generator.state == rng_b.bit_generator.state
        placed_any += got[2]
        held_any += not got[2]
    assert placed_any and held_any  # both paths were taken


def test_the_bound_settles_only_beliefs_whose_mode_and_copies_hold_too_little(hallway):
    """The calibrated keeper (``mcl_calibrated_copies``) skips a belief when no disc holds
    ``KEEP_CHECK_MASS / (1 + copies)``: then its top mode and turned copies together hold
    less than ``KEEP_CHECK_MASS`` (a belief split evenly over the copies holds it all, no
    disc more than a quarter)."""
    from coop_loc_env.backends.mcl import KEEP_CHECK_MASS

    pf = hallway.filters[0]
    syms = hallway.symmetries["sonar"]
    share = KEEP_CHECK_MASS / (1 + len(syms))
    bounds = (0.0, 0.0, *(float(v) for v in hallway.cfg.world_size))
    rng = np.random.default_rng(6)
    settled = held = 0
    for t in range(80):
        copies = {k: int(rng.choice([0, 40, 300])) for k in (1, 2, 3)}
        parts, w = _belief(rng, pf.grid, (0.3, 1.0, 2.0, 6.0)[t % 4], copies)
        if t % 4 == 0:  # spread over the whole ring (a global start)
            parts[:, :2] = pf.grid.sample_free(len(parts), rng)
        elif t % 4 == 1:  # a tight cloud split evenly over the mode and its copies
            quarter = len(parts) // 4
            cloud = TRUE + rng.normal(0.0, [0.3, 0.3, 0.1], (quarter, 3))
            parts[:4 * quarter] = np.concatenate(
                [cloud, *(symmetric_copies(cloud, s) for s in syms)])
            w = np.full(len(parts), 1.0 / len(parts))
        pf.set_particles(parts, w)
        parts, w = pf.particles, pf.weights
        top, _ = top_mode(parts, w, 2.0, TOP_MODE_HEADING_TOL, bounds)
        group = sum(float(w[near_pose(parts, p, 2.0, TOP_MODE_HEADING_TOL)].sum())
                    for p in [top, *(symmetric_copies(top, s) for s in syms)])
        if mode_weight_below(pf.particle_set, 2.0, share):
            settled += 1
            assert group < KEEP_CHECK_MASS
        held += group >= KEEP_CHECK_MASS
    assert settled >= 10 and held >= 15  # both kinds of belief were drawn


def _scan_loglik_along_numpy(table: RangeTable, lut: BeamLUT, origin, angles, poses, scans,
                             occupied_loglik):
    """The trajectory score as numpy code (range-table lookups, likelihood rows)."""
    n, k = poses.shape[:2]
    flat = poses.reshape(-1, 3)
    x = (flat[:, 0] - origin[0]).astype(np.float32)
    y = (flat[:, 1] - origin[1]).astype(np.float32)
    h = flat[:, 2].astype(np.float32)
    expected = table.expected(x, y, h, angles)
    rows = np.broadcast_to(lut.rows(scans)[None], (n, k, len(angles))).reshape(-1, len(angles))
    ll = lut.loglik(expected, rows)
    ll[~table.free(x, y)] += occupied_loglik
    return ll.reshape(n, k).sum(axis=1)


def test_scan_loglik_along_is_the_numpy_score_bit_for_bit(hallway):
    table, lut, angles, max_range = hallway.beam_model(0)
    pf = hallway.filters[0]
    rng = np.random.default_rng(4)
    # trajectories all over the map box and beyond it (walls, outside: the occupied term)
    poses = np.empty((12, 40, 3))
    poses[..., :2] = rng.uniform(-1.0, 21.0, (12, 40, 2))
    poses[..., 2] = rng.uniform(-4.0, 4.0, (12, 40))
    scans = rng.uniform(0.0, max_range * 1.1, (40, len(angles)))
    scans[rng.random(scans.shape) < 0.2] = np.nan
    scans[rng.random(scans.shape) < 0.1] = max_range
    got = scan_loglik_along(table, lut, pf.state_origin, angles, poses, scans,
                            pf.config.occupied_loglik)
    want = _scan_loglik_along_numpy(table, lut, pf.state_origin, angles, poses, scans,
                                    pf.config.occupied_loglik)
    assert np.array_equal(got, want)
    one = scan_loglik_along(table, lut, pf.state_origin, angles, poses[3], scans,
                            pf.config.occupied_loglik)
    assert one == want[3]


def test_each_filters_mode_is_computed_once_per_state(monkeypatch):
    import coop_loc_env.backends.mcl as mcl_backend

    calls = []

    def counting(ps, radius):
        calls.append(ps)
        return filter_mode(ps, radius)

    monkeypatch.setattr(mcl_backend, "filter_mode", counting)
    env = coop_loc_env.parallel_env("active_hallway", n_robots=2, n_particles=300)
    env.reset(seed=1)
    backend = env.backends[0]
    env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
    pf = backend.filters[0]
    first = backend._mode(0, 2.0)
    n = len(calls)
    assert backend._mode(0, 2.0)[0] is first[0] and len(calls) == n  # the same state: cached
    # new particles: computed again, for them
    rng = np.random.default_rng(0)
    pf.set_particles(TRUE + rng.normal(0.0, 0.2, (300, 3)))
    mask, mass = backend._mode(0, 2.0)
    assert len(calls) == n + 1
    assert np.array_equal(mask, main_mode(pf.particles[:, :2], pf.weights, 2.0)[1])
    # steps move the particles in place: never the mode of an earlier state
    act = np.random.default_rng(1)
    for _ in range(4):
        backend._mode(0, 2.0)
        env.step({a: act.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        mask, mass = backend._mode(0, 2.0)
        _, want = main_mode(pf.particles[:, :2], pf.weights, 2.0)
        assert np.array_equal(mask, want)
        assert mass == float(pf.weights[want].sum())
