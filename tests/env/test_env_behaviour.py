"""Full-episode determinism, bad-input errors, and basic physics/sensor behaviour."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test.seed_test import data_equivalence

import coop_loc_env
from coop_loc_env import RobotSpec


def _rollout(scenario: str, seed: int, **kw):
    env = coop_loc_env.parallel_env(scenario, **kw)
    obs, infos = env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed + env.agent_name_mapping[agent])
    trace = [(obs, infos)]
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        trace.append(env.step(actions))
    return trace


@pytest.mark.parametrize("scenario", coop_loc_env.list_scenarios())
def test_full_episode_is_deterministic(scenario):
    kw = {"max_cycles": 60, "n_particles": 200}
    a = _rollout(scenario, 11, **kw)
    b = _rollout(scenario, 11, **kw)
    assert len(a) == len(b) > 1
    for step_a, step_b in zip(a, b, strict=True):
        assert data_equivalence(step_a, step_b)


def test_different_seeds_differ():
    a = _rollout("outdoor_terrain", 1, max_cycles=10)
    b = _rollout("outdoor_terrain", 2, max_cycles=10)
    assert not data_equivalence(a[-1], b[-1])


@pytest.fixture
def env():
    e = coop_loc_env.parallel_env(max_cycles=50, n_robots=2)
    e.reset(seed=0)
    return e


GOOD = np.array([0.2, 0.0], dtype=np.float32)


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"robot_0": [np.nan, 0.0], "robot_1": GOOD}, "robot_0.*NaN"),
        ({"robot_0": [np.inf, 0.0], "robot_1": GOOD}, "robot_0.*NaN or inf"),
        ({"robot_0": GOOD, "robot_1": GOOD, "robot_9": GOOD}, "robot_9"),
        ({"robot_0": [0.1, 0.2, 0.3], "robot_1": GOOD}, "robot_0.*shape"),
        ({"robot_0": 0.5, "robot_1": 0.5}, "shape"),
        ({"robot_0": [1.5, 0.0], "robot_1": GOOD}, "robot_0.*outside"),
        ({"robot_0": "fast", "robot_1": GOOD}, "robot_0.*not numeric"),
        ({"robot_0": GOOD}, "missing.*robot_1"),
    ],
)
def test_bad_actions_raise_and_env_stays_usable(env, bad, match):
    before = env.world.poses.copy()
    with pytest.raises(ValueError, match=match):
        env.step(bad)
    np.testing.assert_array_equal(env.world.poses, before)
    obs, rewards, term, trunc, infos = env.step({"robot_0": GOOD, "robot_1": GOOD})
    assert set(obs) == {"robot_0", "robot_1"}
    assert all(np.isfinite(o).all() for o in obs.values())


def test_unknown_agent_in_space_lookup_raises(env):
    with pytest.raises(ValueError, match="robot_7"):
        env.observation_space("robot_7")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"scenario": "no_such_world"}, "no_such_world"),
        ({"n_robots": 0}, "n_robots.*0"),
        ({"gps_rate": -1.0}, "gps_rate.*-1.0"),
        ({"odom_v_std": -0.1}, "odom_v_std.*-0.1"),
        ({"laser_beams": 0}, "laser_beams"),
        ({"detection_prob": 1.5}, "detection_prob.*1.5"),
        ({"estimator": "kalman"}, "estimator.*kalman"),
        ({"wheel_count": 4}, "wheel_count"),
        ({"dt": float("nan")}, "dt.*nan"),
        ({"world_size": (10.0, -5.0)}, "world_size"),
        ({"team": (RobotSpec(range_sensor="radar"),)}, "radar"),
        ({"render_mode": "ascii"}, "ascii"),
    ],
)
def test_invalid_config_raises_value_error_naming_key(kwargs, match):
    with pytest.raises(ValueError, match=match):
        coop_loc_env.parallel_env(**kwargs)


def test_overrides_apply_and_team_is_heterogeneous():
    team = (RobotSpec(has_gps=True), RobotSpec(has_gps=False, max_speed=0.5))
    env = coop_loc_env.parallel_env(n_robots=4, laser_beams=12, team=team, max_cycles=5)
    assert env.config.laser_beams == 12
    assert len(env.possible_agents) == 4
    assert env.sensors.has_gps.tolist() == [True, False, True, False]
    assert env.world.max_speed.tolist() == [1.0, 0.5, 1.0, 0.5]


def test_truncation_at_max_cycles():
    env = coop_loc_env.parallel_env(max_cycles=7, steep_patches=0)
    env.reset(seed=0)
    steps = 0
    while env.agents:
        _, _, term, trunc, _ = env.step({a: np.zeros(2, np.float32) for a in env.agents})
        steps += 1
    assert steps == 7
    assert all(trunc.values()) and not any(term.values())
    with pytest.raises(ValueError, match="reset"):
        env.step({})


def test_info_keys_and_reward_terms():
    env = coop_loc_env.parallel_env(max_cycles=5)
    env.reset(seed=0)
    _, rewards, _, _, infos = env.step({a: np.zeros(2, np.float32) for a in env.agents})
    for agent, info in infos.items():
        for key in ("true_pose", "est_pose", "pose_cov", "position_error", "heading_error"):
            assert key in info
        assert info["pose_cov"].shape == (3, 3)
        err = np.hypot(*(info["est_pose"][:2] - info["true_pose"][:2]))
        assert info["position_error"] == pytest.approx(err)
        terms = {k: v for k, v in info.items() if k.startswith("reward_")}
        assert "reward_terms" not in terms  # the nested dict is opt-in
        assert rewards[agent] == pytest.approx(sum(terms.values()))
        assert info["reward_localization"] == pytest.approx(-info["position_error"])


def test_observations_never_contain_truth_unless_privileged():
    """The observation's layout names no true quantity, and the privileged one appends the
    true pose (that observations do not depend on the truth is checked by moving it, in
    test_truth_leaks.py)."""
    env = coop_loc_env.parallel_env(max_cycles=5)
    obs, _ = env.reset(seed=0)
    names = env.observations.names
    assert len(names) == env.observation_space("robot_0").shape[0]
    assert not any(n.startswith("true_") for n in names)
    priv = coop_loc_env.parallel_env(max_cycles=5, privileged_obs=True)
    obs, _ = priv.reset(seed=0)
    tail = obs["robot_0"][-4:]
    x, y, th = priv.world.poses[0]
    w, h = priv.config.world_size
    np.testing.assert_allclose(tail, [x / w * 2 - 1, y / h * 2 - 1, np.cos(th), np.sin(th)], 1e-5)


def test_robot_drives_forward_and_stops_at_obstacles():
    env = coop_loc_env.parallel_env(
        n_robots=1, start_poses=((5.0, 20.0, 0.0),), steep_patches=0, n_random_trees=0,
        n_random_rocks=0, n_random_ooi=0, terrain_amplitude=0.0, slip_std=0.0, max_cycles=400,
        obstacles=(coop_loc_env.Obstacle("rock", "circle", center=(10.0, 20.0), radius=1.0),),
    )
    env.reset(seed=0)
    total_contacts = 0
    for _ in range(20):
        _, _, _, _, infos = env.step({"robot_0": np.array([1.0, 0.0], np.float32)})
        total_contacts += infos["robot_0"]["collisions"]
    x = env.world.poses[0, 0]
    # 2 s at 1 m/s: 2 m travelled.
    assert x == pytest.approx(7.0, abs=0.05)
    for _ in range(60):
        _, _, _, _, infos = env.step({"robot_0": np.array([1.0, 0.0], np.float32)})
        total_contacts += infos["robot_0"]["collisions"]
    # The rock's surface is at x = 9, the robot's radius is 0.35.
    assert env.world.poses[0, 0] == pytest.approx(9.0 - 0.35, abs=0.1)
    assert total_contacts >= 1


def test_gps_drops_out_under_canopy():
    tree = coop_loc_env.Obstacle("tree", "circle", center=(20.0, 20.0), radius=0.4,
                                 canopy_radius=4.0)
    kw = dict(n_robots=2, obstacles=(tree,), n_random_trees=0, n_random_rocks=0,
              steep_patches=0, max_cycles=200, gps_multipath_prob=0.0)
    env = coop_loc_env.parallel_env(start_poses=((21.0, 20.0, 0.0), (5.0, 5.0, 0.0)), **kw)
    env.reset(seed=0)
    fixes = np.zeros(2)
    sats = [[], []]
    for _ in range(100):
        _, _, _, _, infos = env.step({a: np.zeros(2, np.float32) for a in env.agents})
        if env._last_readings.satellites.any():
            for i, a in enumerate(env.possible_agents):
                fixes[i] += infos[a]["gps_fix"]
                sats[i].append(infos[a]["satellites"])
    assert fixes[0] == 0 and fixes[1] == 10
    assert max(sats[0]) <= 3 < min(sats[1])


def test_tip_over_terminates_robot():
    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=300)
    env.reset(seed=0)
    cx, cy = env.world.terrain.steep_centers[0]
    start = ((cx - 4.0, cy, 0.0), (2.0, 2.0, 0.0))
    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=300, start_poses=start,
                                    n_random_trees=0, n_random_rocks=0)
    env.reset(seed=0)
    terminated = False
    for _ in range(80):
        _, rewards, term, _, infos = env.step({a: np.array([0.5, 0.0], np.float32)
                                               for a in env.agents})
        if term.get("robot_0"):
            terminated = True
            assert infos["robot_0"]["tipped_over"]
            assert rewards["robot_0"] <= -env.config.tip_over_penalty
            break
    assert terminated
    assert env.agents == ["robot_1"]
