"""Tests of the terrain-mapping estimator (Madhavan, Fregene, Parker, Sec. 5)."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.terrain_fusion import (
    fuse_elevation,
    fusion_weights,
    gps_alt_variance,
    paper_delta_z,
)
from estimators.terrain_map import TerrainMap

EYE = np.eye(3) * 1e-4  # a well-localized robot's pose covariance


def _one(
    m: TerrainMap,
    rid: int,
    x: float,
    y: float,
    *,
    heading: float = 0.0,
    pitch: float = 0.0,
    alt: float = np.nan,
    nos: float = 0.0,
    dist: float = 0.0,
    cov: np.ndarray = EYE,
    base_alt: float = 0.0,
) -> int:
    """Update a single robot; return the cells it newly mapped."""
    out = m.update([rid], [[x, y, heading]], [cov], [pitch], [alt], [nos], [dist], base_alt)
    return int(out[0])


# ------------------------------------------------------------------ fusion weights
@pytest.mark.parametrize(
    ("nos", "f_theta", "f_gps"),
    [
        (0, 0.9, 0.1),
        (4, 0.9, 0.1),
        (5, 0.5, 0.5),
        (7, 0.3, 0.7),
        (10, 0.0, 1.0),
        (11, 0.1, 0.9),
        (15, 0.1, 0.9),
    ],
)
def test_fusion_weights_match_paper_piecewise_formula(nos, f_theta, f_gps):
    ft, fg = fusion_weights(nos)
    assert ft == pytest.approx(f_theta, abs=1e-12)
    assert fg == pytest.approx(f_gps, abs=1e-12)


def test_fusion_weights_vectorized_and_reject_bad_counts():
    ft, fg = fusion_weights(np.array([4, 5, 10, 11]))
    np.testing.assert_allclose(fg, [0.1, 0.5, 1.0, 0.9])
    np.testing.assert_allclose(ft, [0.9, 0.5, 0.0, 0.1])
    for bad in (-1, np.nan, np.inf):
        with pytest.raises(ValueError, match="nos"):
            fusion_weights(bad)


def test_paper_delta_z_is_the_literal_formula():
    theta, lever, zg, zg0 = 0.2, 0.5, 103.0, 100.0
    # NOS = 5: 0.5 * (0.5 * 0.5 * tan(0.2) + 0.5 * 3)
    expected = 0.5 * (0.5 * lever * np.tan(theta) + 0.5 * (zg - zg0))
    assert paper_delta_z(theta, lever, zg, zg0, 5) == pytest.approx(expected)
    # NOS = 11: DGPS dominates
    expected = 0.5 * (0.1 * lever * np.tan(theta) + 0.9 * (zg - zg0))
    assert paper_delta_z(theta, lever, zg, zg0, 11) == pytest.approx(expected)


def test_gps_variance_inversely_proportional_to_satellites():
    np.testing.assert_allclose(gps_alt_variance([5, 10, 20], 0.3), [0.18, 0.09, 0.045])


def test_fuse_elevation_dead_reckons_without_fix_and_follows_gps_at_ten_satellites():
    prev, var = np.array([1.0, 1.0]), np.array([0.0, 0.0])
    d, pitch = np.array([2.0, 2.0]), np.array([0.1, 0.1])
    gps = np.array([np.nan, 5.0])
    nos = np.array([7.0, 10.0])
    z, v = fuse_elevation(prev, var, d, pitch, gps, nos, pitch_std=0.01, gps_alt_std=0.3)
    assert z[0] == pytest.approx(1.0 + 2.0 * np.tan(0.1))  # no fix: inclinometer only
    assert z[1] == pytest.approx(5.0)  # NOS = 10: f_gps = 1
    assert v[0] > 0 and v[1] == pytest.approx(0.09)


def test_fuse_elevation_variance_grows_without_fix_and_shrinks_with_satellites():
    z, v = np.zeros(1), np.full(1, 0.5)
    one = np.ones(1)
    _, v_dr = fuse_elevation(z, v, one, 0.1 * one, np.full(1, np.nan), 0 * one, 0.01, 0.3)
    _, v_4 = fuse_elevation(z, v, one, 0.1 * one, one, 4 * one, 0.01, 0.3)
    _, v_11 = fuse_elevation(z, v, one, 0.1 * one, one, 11 * one, 0.01, 0.3)
    assert v_dr[0] > 0.5 > v_4[0] > v_11[0]


# -------------------------------------------------------------------- registration
def test_sample_registers_at_estimated_pose_not_true_pose():
    m = TerrainMap(1, (10.0, 10.0), resolution=1.0)
    # The robot truly stands at (2.5, 2.5) but believes it is at (6.5, 3.5).
    _one(m, 0, 6.5, 3.5, alt=4.0, nos=10)
    assert m.mapped[6, 3] and not m.mapped[2, 2]
    assert m.elevation[6, 3] == pytest.approx(4.0)
    assert m.mapped.sum() == 1


def test_gps_altitude_is_relative_to_base_station_plus_datum():
    m = TerrainMap(1, (4.0, 4.0), resolution=1.0, datum=2.0)
    _one(m, 0, 0.5, 0.5, alt=103.0, nos=10, base_alt=100.0)
    assert m.elevation[0, 0] == pytest.approx(5.0)
    assert m.robot_elevation([0])[0][0] == pytest.approx(5.0)


def test_map_of_a_slope_from_pitch_only_has_small_rmse_and_pose_error_corrupts_it():
    slope = 0.2
    m = TerrainMap(1, (20.0, 4.0), resolution=0.5, pitch_std=0.0)
    truth = slope * m.cell_centers()[0]
    m.set_robot_elevation(0, slope * 0.25)
    bad = TerrainMap(1, (20.0, 4.0), resolution=0.5, pitch_std=0.0)
    bad.set_robot_elevation(0, slope * 0.25)
    for x in np.arange(0.25, 19.9, 0.5):
        dist = 0.0 if x == 0.25 else 0.5
        _one(m, 0, x, 2.0, pitch=np.arctan(slope), dist=dist)
        _one(bad, 0, x + 2.0, 2.0, pitch=np.arctan(slope), dist=dist)  # 2 m pose error
    assert m.mapped.sum() == 40
    assert m.rmse(truth) < 1e-9
    assert bad.rmse(truth) == pytest.approx(slope * 2.0, rel=1e-6)


def test_footprint_writes_cells_around_robot_extrapolated_along_pitch():
    m = TerrainMap(1, (10.0, 10.0), resolution=1.0, footprint_radius=1.0)
    n = _one(m, 0, 5.5, 5.5, pitch=np.arctan(0.5), alt=3.0, nos=10)
    assert n == 5  # centre + 4 neighbours
    e = m.elevation
    assert e[5, 5] == pytest.approx(3.0)
    assert e[6, 5] == pytest.approx(3.5) and e[4, 5] == pytest.approx(2.5)  # along heading
    assert e[5, 6] == pytest.approx(3.0)  # across heading


def test_samples_off_the_grid_are_dropped():
    m = TerrainMap(2, (5.0, 5.0), resolution=1.0)
    out = m.update(
        [0, 1],
        [[-1.0, 2.0, 0.0], [2.5, 2.5, 0.0]],
        [EYE, EYE],
        [0.0, 0.0],
        [1.0, 1.0],
        [10, 10],
        [0.0, 0.0],
        0.0,
    )
    np.testing.assert_array_equal(out, [0, 1])
    assert m.mapped.sum() == 1


# ------------------------------------------------------------------- coverage
def test_coverage_is_monotone_and_newly_mapped_counts_add_up():
    rng = np.random.default_rng(3)
    m = TerrainMap(4, (20.0, 20.0), resolution=0.5, footprint_radius=0.6)
    drivable = np.ones(m.shape, dtype=bool)
    drivable[:, :5] = False
    poses = np.c_[rng.uniform(2, 18, (4, 2)), rng.uniform(-np.pi, np.pi, 4)]
    cov = np.tile(EYE, (4, 1, 1))
    covs, total, prev = [], 0, 0.0
    for _ in range(300):
        poses[:, 2] += rng.normal(0, 0.3, 4)
        step = rng.uniform(0, 0.4, 4)
        poses[:, 0] = np.clip(poses[:, 0] + step * np.cos(poses[:, 2]), 0, 19.9)
        poses[:, 1] = np.clip(poses[:, 1] + step * np.sin(poses[:, 2]), 0, 19.9)
        nos = rng.integers(0, 12, 4)
        alt = np.where(nos > 0, rng.normal(0, 0.3, 4), np.nan)
        new = m.update(
            np.arange(4),
            poses,
            cov * rng.uniform(1, 100, (4, 1, 1)),
            rng.normal(0, 0.05, 4),
            alt,
            nos,
            step,
            0.0,
        )
        assert new.shape == (4,) and (new >= 0).all()
        assert new.sum() == m.newly_mapped_cells
        total += new.sum()
        c = m.coverage(drivable)
        assert c >= prev
        prev = c
        covs.append(c)
    assert total == m.mapped.sum() == m.n_mapped
    assert covs[-1] > covs[0] > 0
    assert m.coverage() == pytest.approx(m.mapped.mean())
    assert m.coverage(drivable) == pytest.approx((m.mapped & drivable).sum() / drivable.sum())


def test_revisiting_a_cell_is_not_newly_mapped():
    m = TerrainMap(1, (5.0, 5.0), resolution=1.0)
    assert _one(m, 0, 1.5, 1.5, alt=1.0, nos=5) == 1
    assert _one(m, 0, 1.6, 1.4, alt=1.0, nos=11) == 0
    assert m.newly_mapped_cells == 0


# -------------------------------------------------------------------- merging
def test_merge_keeps_higher_confidence_value_in_either_order():
    hi = dict(alt=2.0, nos=11, cov=EYE)  # many satellites, well localized
    lo = dict(alt=np.nan, nos=0, cov=np.eye(3) * 4.0)  # no fix, poorly localized
    for first, second in ((hi, lo), (lo, hi)):
        m = TerrainMap(2, (5.0, 5.0), resolution=1.0)
        m.set_robot_elevation(1, -7.0, var=25.0)  # robot 1 is unsure of its elevation
        rid = {id(hi): 0, id(lo): 1}
        _one(m, rid[id(first)], 2.5, 2.5, **first)
        _one(m, rid[id(second)], 2.5, 2.5, **second)
        # The high-confidence robot 0 measured about 2.0 (0.1 * 0 + 0.9 * 2.0 = 1.8).
        assert m.elevation[2, 2] == pytest.approx(1.8)


def test_same_step_collision_keeps_higher_confidence_sample():
    m = TerrainMap(2, (5.0, 5.0), resolution=1.0)
    m.reset(initial_var=1.0)
    # Robot 0: 5 satellites, poorly localized; robot 1: 10 satellites, well localized.
    out = m.update(
        [0, 1],
        [[2.5, 2.5, 0.0], [2.4, 2.6, 0.0]],
        [np.eye(3), EYE],
        [0.0, 0.0],
        [9.0, 3.0],
        [5, 10],
        [0.0, 0.0],
        0.0,
    )
    assert m.elevation[2, 2] == pytest.approx(3.0)
    np.testing.assert_array_equal(out, [0, 1])  # credit goes to the sample kept


def test_lower_confidence_revisit_by_same_robot_does_not_overwrite():
    m = TerrainMap(1, (5.0, 5.0), resolution=1.0)
    _one(m, 0, 2.5, 2.5, alt=2.0, nos=10)
    # Back after driving without a fix and with a worse pose estimate: less confident.
    _one(m, 0, 2.5, 2.5, pitch=0.1, dist=1.0, nos=0, cov=np.eye(3) * 4.0)
    assert m.robot_elevation([0])[0][0] == pytest.approx(2.0 + np.tan(0.1))
    assert m.elevation[2, 2] == pytest.approx(2.0)
    # Many satellites again: the fused value is more confident and replaces it.
    _one(m, 0, 2.5, 2.5, alt=3.0, nos=11, cov=EYE * 0.01)
    assert m.elevation[2, 2] == pytest.approx(0.1 * (2.0 + np.tan(0.1)) + 0.9 * 3.0)


def test_segment_mode_holds_local_maps_until_end_segment():
    m = TerrainMap(2, (10.0, 10.0), resolution=1.0, merge_every_step=False)
    for x in (0.5, 1.5, 2.5):
        out = m.update(
            [0, 1],
            [[x, 0.5, 0.0], [x, 0.5, 0.0]],
            [EYE, np.eye(3)],
            [0.0, 0.0],
            [1.0, 4.0],
            [10, 10],
            [1.0, 1.0],
            0.0,
        )
        assert (out == 0).all()
    assert m.mapped.sum() == 0 and m.coverage() == 0.0
    assert np.isfinite(m.local_map(0)).sum() == 3
    np.testing.assert_array_equal(m.end_segment([1]), [3])  # robot 1 merges first
    assert m.elevation[1, 0] == pytest.approx(4.0)
    np.testing.assert_array_equal(m.end_segment([0]), [0])  # better values, no new cells
    assert m.elevation[1, 0] == pytest.approx(1.0)  # robot 0 was better localized
    assert np.isnan(m.local_map(0)).all() and m.mapped.sum() == 3


# -------------------------------------------------------- objects, gaps, patches
def test_mark_object_and_terrain_matrix():
    m = TerrainMap(1, (10.0, 10.0), resolution=1.0)
    _one(m, 0, 0.5, 0.5, alt=2.0, nos=10)
    assert m.mark_object(5.5, 5.5, radius=1.0) == 5
    assert m.mark_object(5.5, 5.5) == 0  # already marked
    t = m.terrain_matrix(object_value=1e3)
    assert t[0, 0] == pytest.approx(2.0)
    assert t[5, 5] == t[4, 5] == t[5, 6] == 1e3
    assert t[9, 9] == 0.0 and t[4, 4] == 0.0  # unexplored (Eq. 5)
    assert m.object_mask.sum() == 5 and m.objects == [(5.5, 5.5, 1.0), (5.5, 5.5, 0.0)]
    assert not m.mapped[5, 5]  # objects are a layer, not elevation
    with pytest.raises(ValueError, match="radius"):
        m.mark_object(1.0, 1.0, radius=-1.0)


def test_filled_interpolates_gaps_of_a_smooth_surface():
    m = TerrainMap(1, (10.0, 10.0), resolution=0.5)
    xc, yc = m.cell_centers()
    truth = 0.1 * xc - 0.05 * yc + 0.01 * xc * yc
    # Map every other row and column: the cells in between are gaps.
    for i in range(0, m.shape[0], 2):
        for j in range(0, m.shape[1], 2):
            _one(m, 0, xc[i, j], yc[i, j], alt=truth[i, j], nos=10)
    assert m.coverage() == pytest.approx(0.25)
    f = m.filled()
    inner = np.zeros(m.shape, dtype=bool)
    inner[:-1, :-1] = True  # inside the convex hull of the mapped cells
    assert np.isfinite(f[inner]).all() and np.isnan(f[-1, -1])
    assert np.abs(f[inner] - truth[inner]).max() < 1e-2
    np.testing.assert_allclose(f[m.mapped], m.elevation[m.mapped])
    assert m.coverage() == pytest.approx(0.25)  # filling does not count as mapping
    assert m.rmse(truth, use_filled=True) < 1e-2


def test_filled_with_collinear_samples_leaves_gaps():
    m = TerrainMap(1, (10.0, 10.0), resolution=1.0)
    for x in (0.5, 3.5, 6.5):
        _one(m, 0, x, 0.5, alt=1.0, nos=10)
    f = m.filled()
    assert np.isfinite(f).sum() == 3


def test_rmse_nan_when_nothing_mapped_and_checks_shape():
    m = TerrainMap(1, (4.0, 4.0), resolution=1.0)
    assert np.isnan(m.rmse(np.zeros(m.shape)))
    with pytest.raises(ValueError, match="true_height"):
        m.rmse(np.zeros((3, 3)))


def test_local_patch_is_egocentric():
    m = TerrainMap(1, (10.0, 10.0), resolution=1.0)
    _one(m, 0, 7.5, 5.5, alt=2.0, nos=10)  # a cell 2 m east of (5.5, 5.5)
    m.mark_object(5.5, 7.5)  # an object 2 m north
    east = m.local_patch(np.array([5.5, 5.5, 0.0]), 5)
    north = m.local_patch(np.array([5.5, 5.5, np.pi / 2]), 5, reference=0.5)
    assert east.shape == (3, 5, 5) and east.dtype == np.float32
    # Heading east: the mapped cell is 2 ahead (axis 1), the object 2 to the left (axis 2).
    assert east[1, 4, 2] == 1 and east[0, 4, 2] == pytest.approx(2.0) and east[1].sum() == 1
    assert east[2, 2, 4] == 1 and east[2].sum() == 1
    # Heading north: the mapped cell is 2 to the right, the object 2 ahead.
    assert north[1, 2, 0] == 1 and north[0, 2, 0] == pytest.approx(1.5)
    assert north[2, 4, 2] == 1
    batch = m.local_patch(np.array([[5.5, 5.5, 0.0], [0.5, 0.5, 0.0]]), 5)
    assert batch.shape == (2, 3, 5, 5)
    np.testing.assert_array_equal(batch[0], east)
    assert batch[1, 1].sum() == 0  # off-grid and unmapped cells read as unknown


# ------------------------------------------------------------------ bad input
def test_bad_input_raises_value_error_naming_it():
    m = TerrainMap(2, (5.0, 5.0), resolution=1.0)
    ok = dict(
        est_poses=[[1.0, 1.0, 0.0]],
        pose_covs=[EYE],
        pitch=[0.0],
        gps_alt=[1.0],
        nos=[5],
        distance=[0.0],
        base_alt=0.0,
    )
    with pytest.raises(ValueError, match="robot_ids"):
        m.update([2], **ok)
    with pytest.raises(ValueError, match="robot_ids"):
        m.update([0, 0], **{**ok, "est_poses": [[1, 1, 0]] * 2, "pose_covs": [EYE] * 2})
    with pytest.raises(ValueError, match="est_poses"):
        m.update([0], **{**ok, "est_poses": [[1.0, 1.0]]})
    with pytest.raises(ValueError, match="est_poses"):
        m.update([0], **{**ok, "est_poses": [[np.nan, 1.0, 0.0]]})
    with pytest.raises(ValueError, match="pose_covs"):
        m.update([0], **{**ok, "pose_covs": [np.eye(4)]})
    with pytest.raises(ValueError, match="nos"):
        m.update([0], **{**ok, "nos": [-1]})
    with pytest.raises(ValueError, match="pitch"):
        m.update([0], **{**ok, "pitch": [0.0, 0.1]})
    with pytest.raises(ValueError, match="resolution"):
        TerrainMap(1, (5.0, 5.0), resolution=0.0)
    with pytest.raises(ValueError, match="drivable_mask"):
        m.coverage(np.ones((2, 2), dtype=bool))
    assert m.mapped.sum() == 0  # rejected updates changed nothing
    np.testing.assert_array_equal(m.robot_elevation()[0], [0.0, 0.0])


def test_reset_clears_map_and_sets_start_elevations():
    m = TerrainMap(2, (5.0, 5.0), resolution=1.0)
    _one(m, 0, 1.5, 1.5, alt=1.0, nos=10)
    m.mark_object(3.0, 3.0)
    m.reset(initial_elevation=[1.0, 2.0], initial_var=0.5)
    assert m.mapped.sum() == 0 and m.object_mask.sum() == 0 and m.objects == []
    assert m.n_mapped == 0
    z, v = m.robot_elevation()
    np.testing.assert_array_equal(z, [1.0, 2.0])
    np.testing.assert_array_equal(v, [0.5, 0.5])


# ------------------------------------------------------- kalman weights, end to end
def test_kalman_weights_are_variance_optimal_and_match_paper_without_fix():
    z, one = np.zeros(2), np.ones(2)
    gps, nos = np.array([np.nan, 2.0]), np.array([0.0, 10.0])
    zp, vp = fuse_elevation(z, 0.05 * one, one, 0.1 * one, gps, nos, 0.01, 0.3)
    zk, vk = fuse_elevation(z, 0.05 * one, one, 0.1 * one, gps, nos, 0.01, 0.3, weights="kalman")
    assert zk[0] == pytest.approx(zp[0]) and vk[0] == pytest.approx(vp[0])
    var_inc = 0.05 + (1.0 * (1 + np.tan(0.1) ** 2) * 0.01) ** 2
    gain = var_inc / (var_inc + 0.09)
    assert zk[1] == pytest.approx(np.tan(0.1) + gain * (2.0 - np.tan(0.1)))
    assert vk[1] == pytest.approx((1 - gain) * var_inc) and vk[1] < vp[1]
    with pytest.raises(ValueError, match="weights"):
        fuse_elevation(z, z, z, z, z, nos, 0.01, 0.3, weights="mean")


def _drive_sine_terrain(weights: str, pos_err: float, nos: int) -> float:
    """Three robots cross a sine terrain with noisy sensors; return the map RMSE."""

    def height(x, y):
        return 1.5 * np.sin(x / 6.0) + np.cos(y / 5.0)

    rng = np.random.default_rng(7)
    m = TerrainMap(
        3,
        (30.0, 30.0),
        resolution=0.5,
        datum=height(0.0, 0.0),
        pitch_std=np.deg2rad(0.5),
        gps_alt_std=0.3,
        weights=weights,
    )
    poses = np.array([[1.0, 5.0 + 10.0 * k, 0.0] for k in range(3)])
    m.reset(initial_elevation=height(poses[:, 0], poses[:, 1]))
    covs = np.tile(np.eye(3) * 0.01, (3, 1, 1))
    d = 0.1
    for _ in range(250):
        poses[:, 0] += d
        slope = 1.5 / 6.0 * np.cos(poses[:, 0] / 6.0)  # heading east: d h / d x
        pitch = np.arctan(slope) + rng.normal(0, np.deg2rad(0.5), 3)
        alt = 100.0 + height(poses[:, 0], poses[:, 1]) - height(0.0, 0.0)
        alt += rng.normal(0, 0.3 * np.sqrt(10 / nos), 3)
        est = poses + [pos_err, 0.0, 0.0]
        m.update(np.arange(3), est, covs, pitch, alt, np.full(3, nos), np.full(3, d), 100.0)
    xc, yc = m.cell_centers()
    return m.rmse(height(xc, yc))


def test_end_to_end_map_error_grows_with_pose_error_and_kalman_beats_paper_weights():
    paper = _drive_sine_terrain("paper", 0.0, 11)
    shifted = _drive_sine_terrain("paper", 1.5, 11)
    kalman = _drive_sine_terrain("kalman", 0.0, 11)
    assert paper < 0.4  # about the DGPS altitude noise
    assert shifted > paper + 0.05
    assert kalman < 0.5 * paper


def test_merge_listener_sees_exactly_the_cells_and_values_written():
    m = TerrainMap(3, size=(10.0, 10.0), resolution=0.5, footprint_radius=0.5)
    seen = []
    m.merge_listener = lambda cells, before, after, was_mapped: seen.append(
        (cells.copy(), before.copy(), after.copy(), was_mapped.copy())
    )
    rng = np.random.default_rng(4)
    for step in range(30):
        prev = m.terrain_matrix().ravel(), m.confidence.ravel()
        # Robots 0 and 1 share a spot on some steps (same-step collisions).
        xy = rng.uniform(0.2, 9.8, (3, 2))
        if step % 3 == 0:
            xy[1] = xy[0] + 0.1
        poses = np.c_[xy, rng.uniform(-3, 3, 3)]
        covs = np.tile(EYE, (3, 1, 1)) * rng.uniform(1, 100, (3, 1, 1))
        new = m.update(np.arange(3), poses, covs, rng.normal(0, 0.1, 3), np.nan, 0, 0.1, 0.0)
        cells, before, after, was_mapped = seen[-1]
        changed = np.flatnonzero(m.confidence.ravel() != prev[1])
        assert np.array_equal(np.sort(cells), changed)
        assert np.array_equal(before, prev[0][cells])
        assert np.array_equal(after, m.terrain_matrix().ravel()[cells])
        assert np.array_equal(was_mapped, prev[1][cells] > 0)
        assert new.sum() == np.count_nonzero(~was_mapped)


def test_flat_index_all_inside_shortcut_agrees_with_the_mask():
    # Non-square grid with an origin: points near every edge, inside and out.
    m = TerrainMap(2, size=(6.0, 3.5), resolution=0.5, origin=(-1.0, 2.0))
    rng = np.random.default_rng(9)
    for lo, hi in (((-1.0, 2.0), (5.0, 5.5)), ((-1.3, 1.8), (5.2, 5.7)), ((2.0, 2.0), (4.9, 5.49))):
        xy = rng.uniform(lo, hi, (40, 2))
        flat, inside = m.flat_index_xy(xy)
        flat2, inside2 = m.flat_index_xy(xy, all_inside=True)
        assert np.array_equal(flat, flat2)
        if inside2 is None:
            assert inside.all()
        else:
            assert np.array_equal(inside, inside2)
        i, j, ok = m.world_to_cell(xy)
        assert np.array_equal(ok, inside)
        assert np.array_equal(flat[ok], (i * m.shape[1] + j)[ok])


def test_merges_that_write_nothing_leave_the_map_and_counts_alone():
    m = TerrainMap(3, size=(10.0, 10.0), resolution=0.5, footprint_radius=0.5)
    seen = []
    m.merge_listener = lambda cells, *rest: seen.append(cells.size)
    poses = np.array([[2.2, 2.2, 0.3], [5.1, 5.1, -1.0], [8.0, 3.0, 2.0]])
    first = m.update(np.arange(3), poses, np.tile(EYE, (3, 1, 1)), 0.0, np.nan, 0, 0.0, 0.0)
    assert first.tolist() == [5, 5, 5] and m.n_mapped == 15
    state = m.terrain_matrix(), m.confidence
    for ids in (np.arange(3), np.array([2, 0])):  # whole team, then a subset out of order
        # Less sure of where they are: every sample loses to what the map holds.
        new = m.update(ids, poses[ids], np.tile(EYE * 100, (ids.size, 1, 1)), 0.0, np.nan, 0,
                       0.0, 0.0)
        assert new.tolist() == [0] * ids.size and m.newly_mapped_cells == 0
        assert np.array_equal(m.terrain_matrix(), state[0])
        assert np.array_equal(m.confidence, state[1])
    assert seen == [15, 0, 0] and m.n_mapped == 15
    # A subset out of order gets its own counts back (robot 2's cell at x = 10 is off the grid).
    new = m.update(np.array([2, 0]), poses[[2, 0]] + [1.5, 1.5, 0.0], np.tile(EYE, (2, 1, 1)),
                   0.0, np.nan, 0, 0.0, 0.0)
    assert new.tolist() == [4, 5] and m.n_mapped == 24


@pytest.mark.parametrize(
    "field, value",
    [
        ("est_poses", [[1.0, 1.0, np.inf]]),
        ("est_poses", [[1.0, -np.inf, 0.0]]),
        ("pose_covs", [np.diag([np.inf, np.inf, 1.0])]),  # infinite variance at elevation 0
        ("pose_covs", [EYE * np.nan]),
        ("pitch", [np.nan]),
        ("distance", [np.inf]),
        ("distance", [np.nan]),
    ],
)
def test_non_finite_inputs_are_rejected_before_anything_is_written(field, value):
    m = TerrainMap(2, (5.0, 5.0), resolution=1.0, footprint_radius=1.0)
    ok = dict(est_poses=[[1.0, 1.0, 0.0]], pose_covs=[EYE], pitch=[0.0], gps_alt=[np.nan],
              nos=[0], distance=[0.0], base_alt=0.0)
    with pytest.raises(ValueError, match="finite"):
        m.update([0], **{**ok, field: value})
    assert m.mapped.sum() == 0
    assert m.robot_elevation()[0].tolist() == [0.0, 0.0]


def test_pitch_changed_in_place_is_seen():
    """The tangent terms are kept per pitch values, not per array object."""
    a = TerrainMap(2, (10.0, 10.0), resolution=0.5, footprint_radius=0.5)
    b = TerrainMap(2, (10.0, 10.0), resolution=0.5, footprint_radius=0.5)
    pitch = np.array([0.1, -0.2])
    ids = np.arange(2)
    expected = np.zeros(2)  # dead-reckoned elevation: the rise d * tan(pitch) of each step
    for step in range(6):
        poses = np.array([[1.0 + step, 2.0, 0.3], [6.0, 1.0 + step, 1.2]])
        covs = np.tile(EYE, (2, 1, 1))
        if step % 2:
            pitch[:] = pitch * -1.5  # same array, new values
        a.update(ids, poses, covs, pitch, np.nan, 0, 0.4, 0.0)
        b.update(ids, poses, covs, pitch.copy(), np.nan, 0, 0.4, 0.0)
        b._pitch_key = b""  # b recomputes the tangents every time
        expected = expected + 0.4 * np.tan(pitch)
    np.testing.assert_array_equal(a.elevation, b.elevation)
    np.testing.assert_array_equal(a.robot_elevation()[0], expected)


@pytest.mark.parametrize("radius, every_step", [(0.0, True), (0.6, True), (0.6, False)])
def test_update_prepared_equals_update_for_the_team_and_for_subsets(radius, every_step):
    """The env's entry point (position variance and map-frame DGPS elevation prepared by the
    caller, one read-only id array) writes what update() writes from covariances."""
    kw = dict(size=(12.0, 12.0), resolution=0.5, datum=3.0, footprint_radius=radius,
              merge_every_step=every_step)
    public, prepared = TerrainMap(4, **kw), TerrainMap(4, **kw)
    team = np.arange(4)
    team.flags.writeable = False
    rng = np.random.default_rng(11)
    base = 2.0
    for step in range(25):
        ids = team if step % 3 else np.array([3, 1])
        n = ids.size
        poses = np.c_[rng.uniform(0.5, 11.5, (n, 2)), rng.uniform(-3, 3, n)]
        covs = np.tile(EYE, (n, 1, 1)) * rng.uniform(1, 50, (n, 1, 1))
        pitch, distance = rng.normal(0, 0.1, n), rng.uniform(-0.2, 0.5, n)
        fix = rng.random(n) < 0.5
        gps_alt = np.where(fix, rng.normal(1.0, 0.3, n), np.nan)
        nos = np.where(fix, rng.integers(4, 12, n), 0)
        want = public.update(ids, poses, covs, pitch, gps_alt, nos, distance, base)
        got = prepared.update_prepared(ids, poses, covs[:, 0, 0] + covs[:, 1, 1], pitch,
                                       (prepared.datum - base) + gps_alt, nos.astype(float),
                                       distance)
        assert np.array_equal(got, want)
        assert public.newly_mapped_cells == prepared.newly_mapped_cells
    if not every_step:
        assert np.array_equal(public.end_segment(), prepared.end_segment())
    np.testing.assert_array_equal(prepared.elevation, public.elevation)
    np.testing.assert_array_equal(prepared.confidence, public.confidence)
    for a, b in zip(prepared.robot_elevation(), public.robot_elevation(), strict=True):
        np.testing.assert_array_equal(a, b)
    assert public.mapped.any()


def test_footprint_lists_the_cells_one_sample_writes():
    m = TerrainMap(1, (10.0, 10.0), resolution=1.0, footprint_radius=1.0)
    fp = m.footprint
    assert fp.shape == (5, 2) and fp[0].tolist() == [0.0, 0.0]
    assert sorted(map(tuple, fp[1:].tolist())) == [(-1.0, 0.0), (0.0, -1.0), (0.0, 1.0),
                                                  (1.0, 0.0)]
    new = m.update([0], [[5.5, 5.5, 0.0]], [EYE], 0.0, np.nan, 0, 0.0, 0.0)
    assert new.tolist() == [5] and m.mapped.sum() == 5
    i, j, inside = m.world_to_cell(np.array([5.5, 5.5]) + fp)
    assert inside.all() and m.mapped[i, j].all()
    fp[:] = 0.0  # a copy: the map keeps its own
    assert m.footprint.shape == (5, 2) and np.abs(m.footprint).sum() == 4.0
    assert TerrainMap(1, (10.0, 10.0), resolution=1.0).footprint.tolist() == [[0.0, 0.0]]
