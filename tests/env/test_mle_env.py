"""The centralized team-MLE backend in the env (``estimator="mle"``)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test
from pettingzoo.test.seed_test import data_equivalence

import coop_loc_env
from coop_loc_env import RobotSpec
from coop_loc_env.backends.base import gaussian_features
from coop_loc_env.backends.mle import (
    MLEBackend,
    relative_error_infos,
    relative_feature_names,
    relative_pose_features,
)
from estimators.geometry import relative_pose, wrap_angle
from estimators.mle_online import TeamMLE
from estimators.relative_metrics import (
    ERROR_NAMES,
    relative_errors,
    relative_errors_per_robot,
    relative_pose_matrix,
)

SCENARIOS = coop_loc_env.list_scenarios()
SHORT = {"estimator": "mle", "max_cycles": 12}


def _mle(scenario: str, **kw) -> dict:
    """Overrides that make every robot of ``scenario`` run the MLE (specs may name another)."""
    team = coop_loc_env.make_config(scenario).team
    return {**SHORT, "team": tuple(dataclasses.replace(s, estimator="mle") for s in team), **kw}


def _rollout(scenario: str, seed: int, steps: int, **kw):
    env = coop_loc_env.parallel_env(scenario, **_mle(scenario, max_cycles=steps, **kw))
    obs, infos = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    trace = [(obs, infos)]
    while env.agents:
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        trace.append(env.step(actions))
    return env, trace


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_parallel_api_with_mle(scenario):
    env = coop_loc_env.parallel_env(scenario, **_mle(scenario))
    assert all(isinstance(b, MLEBackend) for b in env.backends)
    parallel_api_test(env, num_cycles=12)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_parallel_seed_with_mle(scenario):
    parallel_seed_test(functools.partial(coop_loc_env.parallel_env, scenario, **_mle(scenario)),
                       num_cycles=12)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_episode_is_deterministic_with_mle(scenario):
    _, a = _rollout(scenario, 5, 15)
    _, b = _rollout(scenario, 5, 15)
    assert len(a) == len(b) == 16
    for step_a, step_b in zip(a, b, strict=True):
        assert data_equivalence(step_a, step_b)
    _, c = _rollout(scenario, 6, 15)
    assert not data_equivalence(a[-1], c[-1])


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_relative_error_infos_on_every_scenario(scenario):
    env, trace = _rollout(scenario, 2, 8)
    infos = trace[-1][4]
    n = env.config.n_robots
    agents = env.possible_agents
    for a, agent in enumerate(agents):
        if n > 1:
            # robot a's mean error over its teammates b of (range, bearing, orientation) of
            # b seen from a, estimated poses against true ones, from the infos alone
            pairs = []
            for other in agents[:a] + agents[a + 1:]:
                est = relative_pose(infos[agent]["est_pose"], infos[other]["est_pose"])
                true = relative_pose(infos[agent]["true_pose"], infos[other]["true_pose"])
                diff = np.asarray(est) - np.asarray(true)
                diff[1:] = wrap_angle(diff[1:])
                pairs.append(np.abs(diff))
            expected = np.mean(pairs, axis=0)
            np.testing.assert_allclose([infos[agent][k] for k in ERROR_NAMES], expected,
                                       rtol=0, atol=1e-9)
        else:
            assert not set(ERROR_NAMES) & set(infos[agent])
    if n > 1:
        per = relative_errors_per_robot(env.estimated_poses, env.world.poses)
        got = np.array([[infos[a][k] for k in ERROR_NAMES] for a in env.possible_agents])
        np.testing.assert_allclose(got, per, rtol=0, atol=1e-12)


def test_observation_embeds_own_belief_and_relative_poses():
    env, trace = _rollout("dispersal", 0, 10)
    obs = trace[-1][0]
    names = env.observations.names
    slots = 3
    own = gaussian_features(env.estimated_poses, env.estimated_covariances,
                            env.config.world_size)
    rel = relative_pose_matrix(env.estimated_poses)
    assert names[: 10 + 6 * slots][10:] == list(relative_feature_names(slots))
    for agent in env.possible_agents:
        i = env.agent_name_mapping[agent]
        o = obs[agent].astype(float)
        np.testing.assert_allclose(o[:10], own[i], atol=1e-5)
        block = o[10 : 10 + 6 * slots].reshape(slots, 6)
        assert np.all(block[:, 0] == 1.0)
        ranges = block[:, 1] * env.config.detector_range
        others = np.delete(rel[i, :, 0], i)
        np.testing.assert_allclose(ranges, np.sort(others)[:slots], atol=1e-4)
        j = int(np.argsort(np.where(np.arange(len(rel)) == i, np.inf, rel[i, :, 0]))[0])
        np.testing.assert_allclose(block[0, 2:], [np.cos(rel[i, j, 1]), np.sin(rel[i, j, 1]),
                                                  np.cos(rel[i, j, 2]), np.sin(rel[i, j, 2])],
                                   atol=1e-5)


def test_relative_slots_pad_and_configure():
    poses = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, np.pi / 2], [0.0, 5.0, 0.0]])
    feats = relative_pose_features(poses, slots=4, range_scale=2.0).reshape(3, 4, 6)
    np.testing.assert_allclose(feats[0, 0], [1.0, 1.0, 1.0, 0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(feats[0, 1, :2], [1.0, 2.5])
    assert np.all(feats[:, 2:] == 0.0)
    assert relative_pose_features(poses[:1], 2, 1.0).shape == (1, 12)
    env = coop_loc_env.parallel_env("circuit", max_cycles=3,
                                    extras={"mle_relative_slots": 1})
    assert env.observations.belief_size == 16
    with pytest.raises(ValueError, match="mle_relative_slots.*-1"):
        coop_loc_env.parallel_env("circuit", max_cycles=3, extras={"mle_relative_slots": -1})


def test_mixed_team_reports_mle_robots_only():
    team = (RobotSpec(estimator="mle", has_gps=False), RobotSpec(estimator="ekf"))
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, team=team, max_cycles=6)
    env.reset(seed=1)
    while env.agents:
        *_, infos = env.step({a: np.array([0.5, 0.1]) for a in env.agents})
    trace = [(None, None, None, None, infos)]
    infos = trace[-1][4]
    for agent in ("robot_0", "robot_2"):
        assert all(np.isfinite(infos[agent][k]) for k in ERROR_NAMES)
    for agent in ("robot_1", "robot_3"):  # same keys, NaN: the EKF robots do not report them
        assert all(np.isnan(infos[agent][k]) for k in ERROR_NAMES)
    backend = next(b for b in env.backends if isinstance(b, MLEBackend))
    np.testing.assert_array_equal(backend.robots, [0, 2])


def test_prior_anchors_the_global_frame():
    """Absolute errors stay at the start-prior scale (the frame is not left floating)."""
    env, trace = _rollout("dispersal", 3, 40)
    err = [trace[-1][4][a]["position_error"] for a in env.possible_agents]
    assert np.mean(err) < 3 * env.config.init_pos_std
    rel = relative_errors(env.estimated_poses, env.world.poses)
    assert rel[0] < 0.2  # crowded: the detections pin the relative poses down


def test_relative_error_infos_helper():
    est = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    true = est.copy()
    true[1, 0] = 1.5
    out = relative_error_infos(est, true, np.array([4, 7, 9]))
    assert set(out) == {4, 7, 9}
    assert out[4]["relative_range_error"] == pytest.approx(0.25)
    assert relative_error_infos(est[:1], true[:1], np.array([0])) == {}


def test_add_odometry_team_matches_sequential_calls():
    rng = np.random.default_rng(0)
    n, s, dt = 3, 37, 0.1
    v = rng.uniform(0, 1, (s, n))
    w = rng.normal(0, 0.5, (s, n))
    sv, sw = 0.02 + 0.1 * v, 0.01 + 0.1 * np.abs(w)
    kw = {"motion_window": 1.0, "initial_std": [0.1, 0.1, 0.1], "anchor": None}
    a, b = TeamMLE(n, **kw), TeamMLE(n, **kw)
    for k in range(s):
        for r in range(n):
            a.add_odometry(r, v[k, r], w[k, r], dt, std=(sv[k, r], sw[k, r]))
    b.add_odometry_team(v[:20], w[:20], dt, sv[:20], sw[:20])
    b.add_odometry_team(v[20:], w[20:], dt, sv[20:], sw[20:])
    assert b.graph.n_nodes == a.graph.n_nodes > n  # windows closed at the same readings
    np.testing.assert_allclose(b.graph.poses[: b.graph.n_nodes],
                               a.graph.poses[: a.graph.n_nodes], atol=1e-12)
    np.testing.assert_allclose(b.poses(), a.poses(), atol=1e-12)
    a.step()
    b.step()
    np.testing.assert_allclose(b.covariances(), a.covariances(), atol=1e-12)
    with pytest.raises(ValueError, match="v and w"):
        b.add_odometry_team(np.zeros(2), np.zeros(2), dt)
    with pytest.raises(ValueError, match="dt"):
        b.add_odometry_team(np.zeros(n), np.zeros(n), -1.0)


def test_gauge_is_fixed_by_one_anchored_robot():
    """Only the first robot's start pose is informative; the others are free (Eq. 15 data only)."""
    env = coop_loc_env.parallel_env("circuit", max_cycles=2)
    env.reset(seed=0)
    backend = next(b for b in env.backends if isinstance(b, MLEBackend))
    cfg = env.config
    priors = backend.mle.graph.priors
    assert len(priors) == cfg.n_robots
    std = np.array([1.0 / np.diag(p.A) for p in priors])
    np.testing.assert_allclose(std[0], [cfg.init_pos_std, cfg.init_pos_std, cfg.init_heading_std])
    assert np.all(std[1:, :2] >= 1e3) and np.all(std[1:, 2] >= np.pi)
    with pytest.raises(ValueError, match="mle_window"):
        coop_loc_env.parallel_env("circuit", extras={"mle_window": 0}).reset(seed=0)
