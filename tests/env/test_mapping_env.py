"""The team terrain map and depth-from-motion camera ranges inside the env."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env import Obstacle


def _drive(env, steps, action=(0.6, 0.15)):
    infos_seq = []
    for _ in range(steps):
        if not env.agents:
            break
        _, _, _, _, infos = env.step({a: np.array(action) for a in env.agents})
        infos_seq.append(infos)
    return infos_seq


def test_coverage_monotone_and_reward_term_counts_truly_covered_cells():
    env = coop_loc_env.parallel_env(n_robots=3, max_cycles=80, reward_coverage_weight=0.25)
    _, infos = env.reset(seed=3)
    prev = infos["robot_0"]["coverage"]
    assert 0.0 < prev < 0.01  # each robot maps the ground it starts on
    total_new = total_covered = 0
    for infos in _drive(env, 80):
        cov = infos["robot_0"]["coverage"]
        assert cov >= prev
        prev = cov
        for info in infos.values():
            assert info["coverage"] == cov  # a team figure
            assert info["reward_coverage"] == pytest.approx(0.25 * info["covered_cells"])
            total_new += info["new_cells"]
            total_covered += info["covered_cells"]
            assert np.isfinite(info["map_rmse"])
    assert total_new > 50  # driving ~4.8 m each with a 0.5 m footprint maps many cells
    assert total_covered > 50  # and truly covers about as many
    assert prev > 0.01
    assert env.terrain_map.n_mapped >= total_new


def test_map_rmse_matches_terrain_map_and_is_small_on_flat_ground():
    env = coop_loc_env.parallel_env(
        n_robots=2, max_cycles=60, terrain_amplitude=0.0, steep_patches=0, init_pos_std=0.0,
        gps_altitude_std=0.05,
    )
    env.reset(seed=0)
    infos = _drive(env, 60)[-1]
    truth = env.mapper.true_height
    assert truth.shape == env.terrain_map.shape
    assert infos["robot_0"]["map_rmse"] == pytest.approx(env.terrain_map.rmse(truth))
    assert infos["robot_0"]["map_rmse"] < 0.1


def test_running_map_metrics_equal_a_full_recount_on_hills():
    """map_rmse and coverage are kept incrementally; they must equal recomputing them."""
    env = coop_loc_env.parallel_env(n_robots=3, max_cycles=120)
    env.reset(seed=5)
    rng = np.random.default_rng(5)
    for _ in range(120):
        if not env.agents:
            break
        _, _, _, _, infos = env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
        info = next(iter(infos.values()))
        terrain_map, mapper = env.terrain_map, env.mapper
        assert info["map_rmse"] == pytest.approx(terrain_map.rmse(mapper.true_height), rel=1e-9)
        assert info["coverage"] == pytest.approx(terrain_map.coverage(mapper.drivable), rel=1e-12)


def test_true_height_grid_orientation_matches_height_field():
    env = coop_loc_env.parallel_env(world_size=(30.0, 20.0), n_robots=1)
    env.reset(seed=0)
    m = env.mapper
    xc, yc = env.terrain_map.cell_centers()
    k = (7, 31)  # x index, y index
    expect = env.world.terrain.elevation(np.array([[xc[k], yc[k]]]))[0]
    assert m.true_height.shape == (60, 40)
    assert m.true_height[k] == pytest.approx(expect)


def test_map_patch_observation():
    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=30, map_patch_obs=5)
    obs, _ = env.reset(seed=1)
    names = env.observations.names
    assert obs["robot_0"].shape == (len(names),)
    i0 = names.index("map_elev_0_0")
    assert names[i0 + 25] == "map_mapped_0_0" and names[i0 + 50] == "map_object_0_0"
    assert names[-1] == "map_object_4_4"
    centre = names.index("map_mapped_2_2")
    assert obs["robot_0"][centre] == 1.0  # the robot mapped the cell it stands on
    _drive(env, 20, action=(1.0, 0.0))
    obs, *_ = env.step({a: np.array([1.0, 0.0]) for a in env.agents})
    behind = obs["robot_0"][names.index("map_mapped_0_2")]
    ahead = obs["robot_0"][names.index("map_mapped_4_2")]
    assert behind == 1.0 and ahead == 0.0  # the path behind is mapped, the ground ahead not


def test_map_patch_obs_off_by_default_and_validated():
    env = coop_loc_env.parallel_env(n_robots=1)
    assert not any(n.startswith("map_") for n in env.observations.names)
    with pytest.raises(ValueError, match="map_patch_obs"):
        coop_loc_env.parallel_env(map_patch_obs=-1)
    with pytest.raises(ValueError, match="map_resolution"):
        coop_loc_env.parallel_env(map_resolution=0.0)
    with pytest.raises(ValueError, match="map_fusion_weights"):
        coop_loc_env.parallel_env(map_fusion_weights="best")
    with pytest.raises(ValueError, match="camera_flow_std_px"):
        coop_loc_env.parallel_env(camera_flow_std_px=-1.0)


def _one_object_scene(**kw):
    return coop_loc_env.parallel_env(
        n_robots=1,
        world_size=(30.0, 30.0),
        obstacles=(Obstacle("ooi", "circle", center=(20.0, 15.0), radius=0.3),),
        n_random_trees=0,
        n_random_rocks=0,
        n_random_ooi=0,
        steep_patches=0,
        terrain_amplitude=0.0,
        start_poses=((8.0, 15.0, 0.0),),
        max_cycles=200,
        **kw,
    )


def _ooi_stds(env, action, steps):
    env.reset(seed=0)
    stds, errs = [], []
    for _ in range(steps):
        env.step({"robot_0": np.array(action)})
        recs = [c for c in env.camera_readings("robot_0") if c.kind == "ooi"]
        assert len(recs) == 1
        true_r = np.hypot(*(env.world.poses[0, :2] - (20.0, 15.0)))
        stds.append(recs[0].range_std)
        errs.append(abs(recs[0].range - true_r))
    return np.array(stds), np.array(errs)


def test_depth_from_motion_range_noise_shrinks_only_with_motion():
    env = _one_object_scene()
    still, _ = _ooi_stds(env, (0.0, 0.0), 20)
    assert np.allclose(still, env.config.camera_range_std)
    # Drive along an arc that keeps the object in view: parallax builds a baseline.
    moving, errs = _ooi_stds(env, (0.5, 0.04), 40)
    assert moving[0] == pytest.approx(env.config.camera_range_std, rel=0.05)
    assert np.all(np.diff(moving) <= 1e-12)
    assert moving[-1] < 0.5 * moving[0]
    # The error of one track scales with its std (same draw), so it shrinks too.
    assert errs[-1] <= errs[0] + 1e-9


def test_depth_from_motion_track_restarts_when_object_leaves_view():
    env = _one_object_scene()
    env.reset(seed=0)
    for _ in range(15):
        env.step({"robot_0": np.array([0.5, 0.04])})
    tracked = env.camera_readings("robot_0")[0]
    assert tracked.frames == 15 and tracked.range_std < env.config.camera_range_std
    for _ in range(12):  # turn away, then back
        env.step({"robot_0": np.array([0.0, 1.0])})
    assert env.camera_readings("robot_0") == []
    for _ in range(12):
        env.step({"robot_0": np.array([0.0, -1.0])})
    again = [c for c in env.camera_readings("robot_0") if c.kind == "ooi"]
    assert again and again[0].frames < 12
    assert again[0].range_std > tracked.range_std
    assert env.last_readings.camera[0][0][3] == pytest.approx(again[0].range)


def test_kalman_fusion_weights_give_a_better_map():
    rmse = {}
    for weights in ("paper", "kalman"):
        env = coop_loc_env.parallel_env(n_robots=2, max_cycles=100, map_fusion_weights=weights)
        env.reset(seed=4)
        rmse[weights] = _drive(env, 100)[-1]["robot_0"]["map_rmse"]
    assert rmse["kalman"] < 0.7 * rmse["paper"]


def test_env_map_equals_the_public_update_fed_the_same_samples():
    """TeamMapper's unchecked path into TerrainMap gives the map update() gives."""
    from estimators.terrain_map import TerrainMap

    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, start_region=None)
    env.reset(seed=5)
    mapper = env.unwrapped.mapper
    calls = []
    core = mapper.map.update_prepared

    def spy(ids, poses, pos_var, pitch, gps_elev, nos, distance):
        calls.append([np.array(a, copy=True) for a in (ids, poses, pos_var, pitch, gps_elev, nos,
                                                        distance)])
        return core(ids, poses, pos_var, pitch, gps_elev, nos, distance)

    start = mapper.map._elev.copy(), mapper.map._conf.copy()
    start_robot = mapper.map.robot_elevation()
    mapper.map.update_prepared = spy
    rng = np.random.default_rng(0)
    for _ in range(40):
        env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
    ref = TerrainMap(4, size=mapper.cfg.world_size, resolution=mapper.cfg.map_resolution,
                     pitch_std=mapper.map.pitch_std, gps_alt_std=mapper.map.gps_alt_std,
                     footprint_radius=mapper.cfg.map_footprint_radius,
                     weights=mapper.map.weights)
    ref._elev[:], ref._conf[:] = start
    ref.set_robot_elevation(np.arange(4), *start_robot)
    base = mapper.cfg.gps_base_altitude
    for ids, poses, pos_var, pitch, gps_elev, nos, distance in calls:
        covs = np.zeros((ids.size, 2, 2))
        covs[:, 0, 0] = pos_var  # P_yy = 0: the same P_xx + P_yy
        ref.update(ids, poses, covs, pitch, gps_elev - (ref.datum - base), nos, distance, base)
    assert len(calls) == 40 and any(np.isfinite(c[4]).any() for c in calls)
    np.testing.assert_allclose(ref.elevation, mapper.map.elevation, rtol=0, atol=1e-12,
                               equal_nan=True)
    assert np.array_equal(ref.mapped, mapper.map.mapped)


def test_height_field_queries_are_clamped_bilinear_on_and_off_the_grid():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, start_region=None)
    env.reset(seed=2)
    t = env.unwrapped.world.terrain
    rng = np.random.default_rng(1)
    pts = np.concatenate([
        rng.uniform(-3, t.width + 3, (500, 2)),
        [[0, 0], [t.width, t.height], [t.width, 0], [-1e-12, 1.0], [t.width + 1, t.height / 2]],
    ])

    def bilinear(grid):  # the textbook formula, clamped to the grid
        f = np.clip(pts / t.resolution, 0, [len(t.xs) - 1.000001, len(t.ys) - 1.000001])
        i, j = f.astype(int).T
        tx, ty = (f - np.floor(f)).T
        low = grid[j, i] + tx * (grid[j, i + 1] - grid[j, i])
        high = grid[j + 1, i] + tx * (grid[j + 1, i + 1] - grid[j + 1, i])
        return low + ty * (high - low)

    assert np.array_equal(t.elevation(pts), bilinear(t.z))
    assert np.array_equal(t.gradient(pts), np.stack([bilinear(t.dzdx), bilinear(t.dzdy)], 1))
    steep = bilinear(t.slope) > t.tip_over_slope
    among = rng.random(len(pts)) < 0.5
    assert np.array_equal(t.is_steep(pts), steep)
    assert np.array_equal(t.is_steep(pts, among), steep & among)
