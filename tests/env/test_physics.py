"""Physics: robots stay out of walls at every accepted speed, contacts cost per step, copies
continue identically."""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.world import MAX_PHYSICS_STEPS, MAX_TRAVEL_PER_RADIUS

FORWARD = np.array([1.0, 0.0], np.float32)


def test_fast_robot_stays_inside_the_world_boundary():
    env = coop_loc_env.parallel_env("circuit", n_robots=1, start_poses=((15.0, 1.5, -math.pi / 2),),
                                    max_speed=2.0)
    env.reset(seed=9)
    lowest = np.inf
    for _ in range(40):  # full speed into the bottom wall, then pressed against it
        env.step({"robot_0": FORWARD})
        lowest = min(lowest, env.world.poses[0, 1])
    assert 0.05 < lowest < 0.3  # in contact with the wall (surface at 0.05 + 0.25), not past it


@pytest.mark.parametrize(("scenario", "speed"), [("symmetric_hallway", 5.0), ("dispersal", 8.0),
                                                 ("circuit", 16.0)])
def test_fast_teams_stay_out_of_walls_and_obstacles(scenario, speed):
    env = coop_loc_env.parallel_env(scenario, max_speed=speed, max_cycles=10**6,
                                    tip_over_terminates=False,
                                    team=(coop_loc_env.RobotSpec(estimator="ekf"),))
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    w, h = env.config.world_size
    for _ in range(60):
        env.step({a: np.array([1.0, rng.uniform(-0.3, 0.3)], np.float32) for a in env.agents})
        xy = env.world.poses[:, :2]
        assert np.all((xy > 0) & (xy < (w, h)))
        assert np.all(env.world.layout.clearance(xy) > 0)  # no centre inside an obstacle


def test_default_speeds_use_one_physics_step_per_substep():
    for scenario in coop_loc_env.list_scenarios():
        assert coop_loc_env.parallel_env(scenario).world.physics_steps == 1


def test_speed_the_physics_cannot_hold_is_refused_with_the_limit():
    # circuit: 0.25 m robots, 0.1 s substeps: 0.4 radius per physics step, 16 steps.
    limit = MAX_PHYSICS_STEPS * MAX_TRAVEL_PER_RADIUS * 0.25 / 0.1
    assert limit == pytest.approx(16.0)
    assert coop_loc_env.parallel_env("circuit", max_speed=limit).world.physics_steps == 16
    with pytest.raises(ValueError, match=rf"max_speed <= {limit:g} m/s"):
        coop_loc_env.parallel_env("circuit", max_speed=limit * 1.01)
    with pytest.raises(ValueError, match="max_speed"):
        coop_loc_env.parallel_env("circuit", team=(coop_loc_env.RobotSpec(max_speed=1e6),))


def test_collision_penalty_is_paid_for_every_step_in_contact():
    rock = coop_loc_env.Obstacle("rock", "circle", center=(10.0, 20.0), radius=1.0)
    env = coop_loc_env.parallel_env(
        n_robots=1, start_poses=((7.0, 20.0, 0.0),), steep_patches=0, n_random_trees=0,
        n_random_rocks=0, n_random_ooi=0, terrain_amplitude=0.0, max_cycles=400,
        obstacles=(rock,), collision_penalty=0.1,
    )
    env.reset(seed=0)
    terms, touching, new = [], [], 0
    for _ in range(60):  # reaches the rock after ~2.5 s and keeps pushing
        _, rewards, _, _, infos = env.step({"robot_0": FORWARD})
        info = infos["robot_0"]
        terms.append(info["reward_collision"])
        touching.append(info["in_contact"])
        new += info["collisions"]
        assert rewards["robot_0"] == pytest.approx(
            sum(v for k, v in info.items() if k.startswith("reward_")))
    touching = np.array(touching)
    assert not touching[:15].any() and touching[-30:].all()
    np.testing.assert_array_equal(np.array(terms), np.where(touching, -0.1, 0.0))
    assert new <= 3 < touching.sum()  # one contact, held: paid per step, counted once


def _run_with_copies(maker, seed, copy_at, horizon, use_pickle):
    env = maker()
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    actions, record, copies = [], [], {}
    for k in range(max(copy_at) + horizon):
        if k in copy_at:
            copies[k] = pickle.loads(pickle.dumps(env)) if use_pickle else copy.deepcopy(env)
        act = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        _, rewards, _, _, infos = env.step(act)
        actions.append(act)
        record.append((env.world.poses.copy(), rewards,
                       {a: (i["collisions"], i.get("in_contact")) for a, i in infos.items()}))
    for k, twin in copies.items():
        for j in range(k, k + horizon):
            _, rewards, _, _, infos = twin.step(actions[j])
            poses, rewards_ref, contacts_ref = record[j]
            assert np.array_equal(twin.world.poses, poses), (k, j)
            assert rewards == rewards_ref, (k, j)
            assert {a: (i["collisions"], i.get("in_contact")) for a, i in infos.items()} == \
                contacts_ref, (k, j)


@pytest.mark.parametrize("use_pickle", [False, True])
def test_copies_made_near_contacts_continue_identically(use_pickle):
    # circuit, seed 32: robots press against walls around these steps.
    maker = lambda: coop_loc_env.parallel_env("circuit", max_cycles=10**6)  # noqa: E731
    _run_with_copies(maker, 32, {100, 112, 121, 130}, 30, use_pickle)


def test_coverage_reward_counts_true_coverage_not_estimate_drift():
    # A robot standing still with very noisy wheel odometry and no absolute sensor: its
    # estimate wanders, so the map gains cells at the estimated pose; the reward gains none.
    env = coop_loc_env.parallel_env(
        n_robots=1, start_poses=((20.0, 20.0, 0.0),), steep_patches=0, n_random_trees=0,
        n_random_rocks=0, n_random_ooi=0, terrain_amplitude=0.0, max_cycles=400,
        reward_coverage_weight=1.0, odom_v_std=4.0,
        team=(coop_loc_env.RobotSpec(has_gps=False, has_compass=False, has_detector=False),),
    )
    env.reset(seed=0)
    mapped = covered = reward = 0.0
    for _ in range(100):
        _, _, _, _, infos = env.step({"robot_0": np.zeros(2, np.float32)})
        info = infos["robot_0"]
        mapped += info["new_cells"]
        covered += info["covered_cells"]
        reward += info["reward_coverage"]
    assert info["position_error"] > 0.5  # the estimate wandered off
    assert mapped > 5 and covered == 0 and reward == 0.0
    # Driving covers ground: truly new drivable cells only, each counted once.
    for _ in range(30):
        _, _, _, _, infos = env.step({"robot_0": FORWARD})
        covered += infos["robot_0"]["covered_cells"]
    mapper = env.mapper
    assert covered > 5
    assert covered + 5 == np.count_nonzero(mapper._truly_covered)  # + the 5 start cells
    assert not np.any(mapper._truly_covered & ~mapper._drivable_flat)


def test_a_cell_two_robots_cover_at_once_counts_for_the_lower_index():
    env = coop_loc_env.parallel_env(n_robots=3, steep_patches=0, n_random_trees=0,
                                    n_random_rocks=0, n_random_ooi=0)
    env.reset(seed=0)
    mapper = env.mapper
    poses = np.array([[30.2, 30.2, 0.0], [10.2, 10.2, 0.0], [30.2, 30.2, 0.0]])
    new = mapper.cover(poses, np.arange(3))
    np.testing.assert_array_equal(new, [5, 5, 0])  # robot 2 stands where robot 0 does
    np.testing.assert_array_equal(mapper.cover(poses, np.arange(3)), [0, 0, 0])
