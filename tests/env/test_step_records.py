"""A step as values: the physics outcome, the readings and the beliefs are records."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.records import PhysicsOutcome


def _drive(env, steps: int, action=(0.6, 0.2)):
    for _ in range(steps):
        env.step({a: np.array(action) for a in env.agents})


def test_readings_are_frozen_and_say_which_sensors_fired():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, gps_rate=2.0)
    env.reset(seed=0)
    fired = []
    for _ in range(10):
        _drive(env, 1)
        readings = env.last_readings
        fired.append(readings.fired.gps)
        if not readings.fired.gps:
            assert not readings.gps_mask.any() and not readings.satellites.any()
    assert fired == [False, False, False, False, True] * 2  # 2 Hz at 10 Hz steps
    with pytest.raises(AttributeError):
        readings.gps_mask = np.ones(2, dtype=bool)


def test_world_step_returns_one_contact_record_with_a_pose_snapshot():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=3)
    env.reset(seed=1)
    world = env.world
    active = np.ones(3, dtype=bool)
    rng = np.random.default_rng(0)
    first = world.step(np.full(3, 0.5), np.zeros(3), active, rng)
    assert isinstance(first, PhysicsOutcome)
    kept = first.poses.copy()
    world.step(np.full(3, 0.5), np.zeros(3), active, rng)
    np.testing.assert_array_equal(first.poses, kept)  # the record is not the world's array
    assert not np.array_equal(world.poses, kept)
    np.testing.assert_array_equal(first.in_contact, first.touching | (first.new_contacts > 0))


def test_bumper_and_contact_infos_come_from_the_physics_outcome():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=1, max_cycles=400,
                                    start_poses=((1.0, 10.0, np.pi),))
    env.reset(seed=0)
    pressed = []
    for _ in range(20):  # drive into the world's west wall
        _, _, _, _, infos = env.step({"robot_0": np.array([1.0, 0.0])})
        bumper = bool(env.last_readings.bumper[0])
        pressed.append(bumper)
        if bumper:
            assert infos["robot_0"]["in_contact"]
    assert any(pressed)


def test_team_beliefs_hold_every_robots_estimate_and_particles():
    env = coop_loc_env.parallel_env("symmetric_hallway", n_robots=2, n_particles=200)
    env.reset(seed=3)
    _drive(env, 2)
    beliefs = env.beliefs
    np.testing.assert_array_equal(beliefs.mean, env.estimated_poses)
    np.testing.assert_array_equal(beliefs.cov, env.estimated_covariances)
    backend = env.backends[0]
    samples = beliefs.samples
    assert sorted(samples) == [0, 1]
    for local, robot in enumerate(backend.robots.tolist()):
        pf = backend.particle_filter(local)
        np.testing.assert_array_equal(samples[robot].states, pf.particles)
        assert samples[robot].ess == pf.ess
    _drive(env, 1)
    unread = env.beliefs  # its particle sets never read during its step
    _drive(env, 1)
    with pytest.raises(RuntimeError, match="earlier step"):
        unread.samples  # noqa: B018 (a property read)
    np.testing.assert_array_equal(beliefs.samples[0].states, samples[0].states)  # snapshot


def test_gaussian_teams_have_no_particle_samples():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, estimator="ekf")
    env.reset(seed=0)
    assert env.beliefs.samples == {}
    assert env.backends[0].particle_filter(0) is None


def test_an_older_readings_keeps_its_own_camera_frame():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=3, max_cycles=100)
    env.reset(seed=4)
    _drive(env, 5, (0.3, 0.05))
    held = env.last_readings
    _drive(env, 5, (0.3, 0.05))
    late = held.camera_records  # read five steps later
    other = coop_loc_env.parallel_env("outdoor_terrain", n_robots=3, max_cycles=100)
    other.reset(seed=4)
    _drive(other, 5, (0.3, 0.05))
    assert late == other.last_readings.camera_records and any(late)


def test_renderer_imports_no_env_module():
    source = Path(coop_loc_env.__file__).with_name("rendering.py").read_text()
    imported = {node.module for node in ast.walk(ast.parse(source))
                if isinstance(node, ast.ImportFrom)}
    assert "coop_loc_env.env" not in imported
