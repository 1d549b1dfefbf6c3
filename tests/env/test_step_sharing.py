"""Per-step results shared between modules give what each module computes on its own."""

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.depth_from_motion import DepthFromMotion
from estimators.terrain_map import TerrainMap


def _env(n=4, **kw):
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=n, max_cycles=10**9,
                                    estimator="ekf", start_region=None, **kw)
    env.reset(seed=3)
    return env


def test_is_steep_among_is_the_masked_test():
    env = _env()
    terrain = env.world.terrain
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 40, (400, 2))
    for cx, cy in terrain.steep_centers:  # points on the steep patches too
        pts = np.concatenate([pts, np.array([cx, cy]) + rng.normal(0, 2, (50, 2))])
    among = rng.random(len(pts)) < 0.7
    full = terrain.is_steep(pts)
    assert full.any()
    np.testing.assert_array_equal(terrain.is_steep(pts, among), full & among)
    np.testing.assert_array_equal(terrain.is_steep(pts, np.zeros(len(pts), bool)), False)


def test_depth_from_camera_sightings_matches_depth_from_camera_lists():
    env = _env(5)
    sensors, cfg = env.sensors, env.config
    n_ooi = len(env.world.layout.ooi_centers)
    by_lists, by_arrays = DepthFromMotion(cfg, n_ooi), DepthFromMotion(cfg, n_ooi)
    by_lists.reset(env.world.poses)
    by_arrays.reset(env.world.poses)
    rng = np.random.default_rng(1)
    seen = 0
    sensors.camera_lists = True
    for _ in range(150):
        env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
        poses = env.world.poses
        mask = rng.random(len(poses)) < 0.8
        cam, sightings = sensors.camera_frame(poses, np.random.default_rng(2), mask)
        a = by_lists.process(cam, mask, poses, env.world.layout.ooi_centers,
                             np.random.default_rng(3))
        b = by_arrays.process([[] for _ in cam], mask, poses, env.world.layout.ooi_centers,
                              np.random.default_rng(3), sightings)
        assert a == b
        seen += sum(len(r) for r in a)
    assert seen > 50
    np.testing.assert_array_equal(by_lists.baseline, by_arrays.baseline)
    np.testing.assert_array_equal(by_lists.frames, by_arrays.frames)


def test_latched_features_stay_views_of_one_block_after_copy_and_pickle():
    import copy
    import pickle

    env = _env()
    rng = np.random.default_rng(0)
    for _ in range(12):
        env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
    for clone in (copy.deepcopy(env), pickle.loads(pickle.dumps(env))):
        ob = clone.observations
        for block in (ob.gps, ob.incl, ob.range, ob.det):
            assert np.shares_memory(block, ob._latched)
        r1, r2 = np.random.default_rng(4), np.random.default_rng(4)
        twin = copy.deepcopy(env)
        for _ in range(15):
            o1 = twin.step({a: r1.uniform(-1, 1, 2) for a in twin.agents})[0]
            o2 = clone.step({a: r2.uniform(-1, 1, 2) for a in clone.agents})[0]
            assert o1.keys() == o2.keys()
            assert all(np.array_equal(o1[k], o2[k]) for k in o1)


def test_fan_caster_reuses_read_only_radii_with_the_same_hits():
    env = _env(6)
    sensors = env.sensors
    caster = sensors._ray_groups[0][1]
    const = sensors._robot_radii
    assert not const.flags.writeable
    rng = np.random.default_rng(0)
    for _ in range(5):
        env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
        poses = env.world.poses
        fresh = caster.cast(poses, poses[:, :2], const.copy())  # writeable: not cached
        np.testing.assert_array_equal(caster.cast(poses, poses[:, :2], const), fresh)
        np.testing.assert_array_equal(caster.cast(poses, poses[:, :2], const), fresh)
        other = np.full(len(poses), 0.5)  # a different radius is not served from the cache
        caster.cast(poses, poses[:, :2], other)
        np.testing.assert_array_equal(caster.cast(poses, poses[:, :2], const), fresh)


def test_caches_follow_the_values_not_the_array_object():
    env = _env(6)
    caster = env.sensors._ray_groups[0][1]
    poses = env.world.poses
    base = np.array(env.sensors._robot_radii)
    radii = base.view()
    radii.flags.writeable = False  # a read-only view of data that can still change
    caster.cast(poses, poses[:, :2], radii)  # cached
    base[:] = 2.0
    np.testing.assert_array_equal(
        caster.cast(poses, poses[:, :2], radii), caster.cast(poses, poses[:, :2], radii.copy())
    )
    tmap = TerrainMap(3, (10.0, 10.0), resolution=1.0)
    base = np.array([0, 1])
    ids = base.view()
    ids.flags.writeable = False
    tmap.set_robot_elevation(ids, 0.0)  # checked and cached
    base[:] = [2, 2]
    with pytest.raises(ValueError, match="must not repeat"):
        tmap.set_robot_elevation(ids, 0.0)
    base[:] = [5, 7]
    with pytest.raises(ValueError, match=r"must lie in \[0, 3\)"):
        tmap.set_robot_elevation(ids, 0.0)
