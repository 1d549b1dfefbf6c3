"""The GPS block of the observation follows the receiver, also when it loses every satellite."""

import numpy as np

import coop_loc_env


def test_gps_features_drop_when_every_robot_loses_its_satellites():
    tree = coop_loc_env.Obstacle("tree", "circle", center=(20.0, 20.0), radius=0.4,
                                 canopy_radius=4.0)
    env = coop_loc_env.parallel_env(
        n_robots=1, start_poses=((13.0, 20.0, 0.0),), obstacles=(tree,), n_random_trees=0,
        n_random_rocks=0, n_random_ooi=0, steep_patches=0, terrain_amplitude=0.0,
        gps_canopy_satellites=(0, 0), gps_multipath_prob=0.0, max_cycles=200,
    )
    env.reset(seed=0)
    names = env.observations.names
    fix_col, sat_col = names.index("gps_fix"), names.index("gps_satellites")
    seen_fix = False
    for _ in range(100):  # drive into the trunk: deep under the canopy from x = 18 m
        obs, _, _, _, infos = env.step({"robot_0": np.array([1.0, 0.0], np.float32)})
        seen_fix |= bool(obs["robot_0"][fix_col] == 1.0)
    assert seen_fix  # it had a fix in the open
    assert env.world.poses[0, 0] > 18.5
    assert not infos["robot_0"]["gps_fix"] and infos["robot_0"]["satellites"] == 0
    assert obs["robot_0"][fix_col] == 0.0 and obs["robot_0"][sat_col] == 0.0
