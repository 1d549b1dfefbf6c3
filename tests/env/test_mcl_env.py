"""The env with ``estimator="mcl"``: PettingZoo API, seeding, determinism, beliefs and infos."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

import coop_loc_env
from coop_loc_env.backends.mcl import MCLBackend, beam_angles, known_map
from coop_loc_env.config import RobotSpec
from coop_loc_env.sensors import SensorSuite
from estimators.mcl.filter import belief_feature_names

SCENARIOS = coop_loc_env.list_scenarios()
# Small particle sets and short episodes keep this fast.
FAST = {"estimator": "mcl", "n_particles": 40, "max_cycles": 8}


def _make(scenario: str, **kw) -> coop_loc_env.CoopLocParallelEnv:
    return coop_loc_env.parallel_env(scenario, **{**FAST, **kw})


def _rollout(env, seed: int, steps: int):
    """Fixed-action rollout; returns the stacked observations and infos."""
    obs, infos = env.reset(seed=seed)
    rng = np.random.default_rng(123)
    trace = [np.stack([obs[a] for a in env.possible_agents])]
    spreads = []
    for _ in range(steps):
        if not env.agents:
            break
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        obs, _, _, _, infos = env.step(actions)
        trace.append(np.stack([obs[a] for a in env.possible_agents if a in obs]))
        spreads.append([infos[a]["particle_spread"] for a in infos])
    return trace, spreads


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_parallel_api_with_mcl(scenario):
    parallel_api_test(_make(scenario), num_cycles=8)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_parallel_seed_with_mcl(scenario):
    parallel_seed_test(functools.partial(_make, scenario), num_cycles=8)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_episode_is_deterministic_with_mcl(scenario):
    a, sa = _rollout(_make(scenario), seed=5, steps=6)
    b, sb = _rollout(_make(scenario), seed=5, steps=6)
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(sa, sb)
    c, _ = _rollout(_make(scenario), seed=6, steps=6)
    assert not np.array_equal(a[-1], c[-1])


def test_mcl_observation_layout_and_infos():
    env = _make("outdoor_terrain", n_robots=2)
    obs, infos = env.reset(seed=0)
    names = env.observations.names
    feat = belief_feature_names(5, 8)
    assert names[: len(feat)] == feat
    assert len(feat) == MCLBackend.feature_size == 48
    o = obs["robot_0"]
    assert o.shape == env.observation_space("robot_0").shape
    hist = o[names.index("hist_r0_c0") : names.index("hist_outside") + 1]
    assert hist.sum() == pytest.approx(1.0, abs=1e-5)
    heading = o[names.index("heading_hist_0") : names.index("heading_hist_7") + 1]
    assert heading.sum() == pytest.approx(1.0, abs=1e-5)
    assert 0 < o[names.index("ess_fraction")] <= 1
    info = infos["robot_0"]
    for key in ("est_pose", "pose_cov", "particle_spread", "n_particles", "position_error"):
        assert key in info
    backend = env.backends[0]
    pf = backend.filters[0]
    np.testing.assert_allclose(info["est_pose"], pf.mean_pose())
    np.testing.assert_allclose(info["pose_cov"], pf.belief().cov)
    parts = pf.particles
    dist = np.hypot(parts[:, 0] - info["true_pose"][0], parts[:, 1] - info["true_pose"][1])
    assert info["particle_spread"] == pytest.approx(float(np.dot(pf.weights, dist)))
    assert info["n_particles"] <= env.config.n_particles


def test_tracking_stays_close_outdoors():
    """Position tracking with DGPS, compass and laser: errors of a few decimetres.

    Bands from the final errors of 2 robots x 16 seeds (0-15) of this run: per robot mean
    0.223 m, sd 0.072, max 0.458 (spread: the same to 0.003 m); means over the four
    4-seed groups 0.180-0.265 m (sd 0.035). Mean band 0.37 m = 0.265 + 3 x 0.035; per-robot
    band 0.67 m = 0.458 + 3 x 0.072.
    """
    errors, spreads = [], []
    for seed in range(4):
        env = coop_loc_env.parallel_env(
            "outdoor_terrain", estimator="mcl", n_particles=300, max_cycles=60, n_robots=2
        )
        env.reset(seed=seed)
        while env.agents:
            _, _, _, _, infos = env.step({a: np.array([0.6, 0.2]) for a in env.agents})
        errors += [info["position_error"] for info in infos.values()]
        spreads += [info["particle_spread"] for info in infos.values()]
    assert np.mean(errors) < 0.37 and max(errors) < 0.67
    assert np.mean(spreads) < 0.37 and max(spreads) < 0.67


def test_backend_fix_rows_match_each_filter():
    """The backend's DGPS / compass rows equal each filter's own."""
    env = coop_loc_env.parallel_env("outdoor_terrain", estimator="mcl", n_particles=50,
                                    n_robots=3)
    env.reset(seed=2)
    backend = env.unwrapped.backends[0]
    u = env.unwrapped
    readings = u.sensors.read(0, u.world.poses, np.zeros((3, 2)), np.random.default_rng(0),
                              np.ones(3, dtype=bool))
    readings = dataclasses.replace(
        readings, gps_xy=np.array([[3.0, 4.0], [0.0, 0.0], [20.0, 30.0]]),
        gps_var=np.array([0.5, 1.0, 2.0]), compass=np.array([0.1, -3.0, 0.0]))
    gps = [True, False, True]
    compass = [True, True, False]
    rows = backend._fixes([0, 1, 2], gps, compass, readings)
    std = env.unwrapped.config.compass_std
    for i, pf in enumerate(backend.filters):
        expected = pf.fix_row(readings.gps_xy[i] if gps[i] else None,
                              float(readings.gps_var[i]) if gps[i] else 1.0,
                              float(readings.compass[i]) if compass[i] else None, std)
        np.testing.assert_allclose(rows[i], expected, rtol=1e-15)


def test_team_mixes_ekf_and_mcl():
    team = (RobotSpec(estimator="ekf"), RobotSpec(estimator="mcl"))
    env = coop_loc_env.parallel_env(
        "outdoor_terrain", team=team, n_robots=4, n_particles=50, max_cycles=5
    )
    kinds = sorted(type(b).__name__ for b in env.backends)
    assert kinds == ["EKFBackend", "MCLBackend"]
    obs, infos = env.reset(seed=0)
    assert infos["robot_1"]["particle_spread"] >= 0  # the EKF robot has it as NaN
    assert np.isnan(infos["robot_0"]["particle_spread"])
    # EKF rows carry their 10 Gaussian features, zero-padded to the MCL's 48
    assert np.all(obs["robot_0"][10:48] == 0)
    while env.agents:
        env.step({a: np.array([0.3, 0.0]) for a in env.agents})


def test_beam_angles_match_the_sensors():
    env = _make("hexagon")
    suite = SensorSuite(env.config, env.world)
    for i in range(env.config.n_robots):
        sonar = env.config.robot_spec(i).range_sensor == "sonar"
        np.testing.assert_array_equal(beam_angles(env.config, sonar), suite.beam_angles[i])


def test_known_maps_honour_visible_to():
    env = _make("hexagon")
    res = 0.25
    laser = known_map(env.world, "laser", res)
    sonar = known_map(env.world, "sonar", res)
    assert laser is known_map(env.world, "laser", res)  # cached
    sonar_only = [o for o in env.world.layout.obstacles if o.visible_to == ("sonar",)]
    laser_only = [o for o in env.world.layout.obstacles if o.visible_to == ("laser",)]
    assert len(sonar_only) == 3 and len(laser_only) == 4

    def inside(o):  # a point inside the (convex) feature
        return np.mean(o.vertices, axis=0) if o.shape == "polygon" else np.array(o.center)

    for o in sonar_only:
        assert not sonar.is_free(inside(o)) and laser.is_free(inside(o))
    for o in laser_only:
        assert not laser.is_free(inside(o)) and sonar.is_free(inside(o))
    # walls at the world's edges: the border ring lies just outside
    assert laser.bounds[0] == pytest.approx(-res)
    with pytest.raises(ValueError, match="radar"):
        known_map(env.world, "radar", res)


def test_global_localization_starts_uniform_and_gaussian_otherwise():
    env = _make("symmetric_hallway", n_particles=400)
    _, infos = env.reset(seed=0)
    assert np.mean([i["particle_spread"] for i in infos.values()]) > 5.0
    env = _make("symmetric_hallway", n_particles=400, global_localization=False)
    _, infos = env.reset(seed=0)
    assert np.mean([i["particle_spread"] for i in infos.values()]) < 1.5


def test_cooperative_updates_switch_transfers():
    kw = dict(n_particles=200, max_cycles=20)
    for coop in (True, False):
        env = _make("hexagon", cooperative_updates=coop, **kw)
        env.reset(seed=0)
        while env.agents:
            _, _, _, _, infos = env.step({a: np.array([0.2, 0.3]) for a in env.agents})
        used = sum(i["detections_used"] for i in infos.values())
        assert (used > 0) == coop


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"global_localization": 1}, "global_localization"),
        ({"extras": {"mcl_resolution": -1.0}}, "mcl_resolution"),
        ({"extras": {"mcl": {"bogus": 1}}}, "bogus"),
        ({"extras": {"mcl_laser": {"bogus": 1}}}, "bogus"),
        ({"extras": {"mcl_sonar": 0.3}}, "mcl_sonar"),
        ({"extras": {"mcl_laser_model": "sonar"}}, "mcl_laser_model"),
        ({"extras": {"mcl_detection_exponent": 0.0}}, "mcl_detection_exponent"),
        ({"extras": {"mcl_detection_exponent": 1.5}}, "mcl_detection_exponent"),
        ({"extras": {"mcl_global_init_factor": 0}}, "mcl_global_init_factor"),
    ],
)
def test_bad_mcl_settings_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        _make("outdoor_terrain", **kwargs)


def test_per_sensor_settings_and_the_laser_beam_model():
    env = _make("hexagon", n_particles=300, max_cycles=4)
    backend = env.backends[0]
    # the hexagon's settings: lasers use the beam model with their own sigma,
    # both types share the tempering; a smaller n_particles caps n_min
    laser, sonar = backend.mcl_config["laser"], backend.mcl_config["sonar"]
    assert backend._laser_beam and laser.beam_lookup_bins > 0
    assert laser.beam_sigma == pytest.approx(0.3) and sonar.beam_sigma == pytest.approx(0.5)
    assert laser.likelihood_exponent == sonar.likelihood_exponent
    assert laser.n_min == laser.n_max == 300
    assert backend.transfer.config.exponent == pytest.approx(0.2)
    obs, infos = env.reset(seed=0)
    assert all(pf.n_particles == 3000 for pf in backend.filters)  # 10x at the start
    while env.agents:
        obs, _, _, _, infos = env.step({a: np.array([0.3, 0.1]) for a in env.agents})
    assert all(np.isfinite(i["particle_spread"]) for i in infos.values())
    # the default elsewhere: likelihood field for lasers, untempered transfers
    env = _make("symmetric_hallway")
    assert not env.backends[0]._laser_beam
    assert env.backends[0].transfer.config.exponent == 1.0


def test_reading_the_particles_leaves_the_filter_untouched():
    """A policy reading a belief must not change how it evolves (the float32 state is not
    re-wrapped early by a read): two copies, one read at every step, stay bit-identical."""
    envs = [coop_loc_env.parallel_env("active_hallway", max_cycles=40) for _ in range(2)]
    for env in envs:
        env.reset(seed=5)
    action = np.array([0.6, 1.0], dtype=np.float32)  # circling: headings cross +-pi often
    for _ in range(30):
        for k, env in enumerate(envs):
            env.step({a: action for a in env.agents})
            if k == 1:
                for pf in env.backends[0].filters:
                    assert pf.particles.shape[1] == 3
    for pa, pb in zip(envs[0].backends[0].filters, envs[1].backends[0].filters, strict=True):
        assert np.array_equal(pa.particles, pb.particles)
        assert np.array_equal(pa.weights, pb.weights)


def test_reset_loads_the_detection_kernels():
    # The first robot detection of a process would otherwise load the density-tree
    # kernels inside an env step (about 10 ms); a fresh interpreter shows whether
    # reset did it.
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import coop_loc_env\n"
        "from estimators.mcl._kernels import grow_tree, tree_density\n"
        "env = coop_loc_env.parallel_env('symmetric_hallway', n_robots=2, n_particles=50)\n"
        "env.reset(seed=0)\n"
        "print(len(grow_tree.signatures), len(tree_density.signatures))\n"
    )
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                         text=True, check=True, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(root)})
    counts = [int(v) for v in out.stdout.split()]
    assert len(counts) == 2 and min(counts) >= 1, out.stdout


# A 10 m x 6 m room with boxes placed without symmetry (the room of
# tests/estimators/mcl/test_particle_filter.py), for a laser-only robot.
ROOM_BOXES = [(2.0, 2.0, 3.0, 2.6), (6.5, 3.2, 7.0, 4.2), (4.5, 0.0, 4.8, 1.2),
              (8.0, 1.0, 9.0, 1.5), (3.5, 5.4, 4.5, 6.0), (5.8, 2.8, 6.1, 3.1),
              (9.5, 5.5, 10.0, 6.0)]


def _kidnap_recovered(seed: int, **overrides) -> bool:
    """Track for 40 steps, move the robot's body to the free spot farthest away (odometry
    does not notice), drive on for 100 steps: is the particle spread below 0.5 m over the
    last 10?"""
    from policies.scripted.wander import WanderPolicy

    room = tuple(coop_loc_env.Obstacle("rock", "polygon",
                                       vertices=((x0, y0), (x1, y0), (x1, y1), (x0, y1)))
                 for x0, y0, x1, y1 in ROOM_BOXES)
    env = coop_loc_env.parallel_env(
        "outdoor_terrain", world_size=(10.0, 6.0), obstacles=room, n_random_trees=0,
        n_random_rocks=0, n_random_ooi=0, steep_patches=0, terrain_amplitude=0.0,
        estimator="mcl", n_robots=1, n_particles=1000, max_cycles=400,
        team=(RobotSpec(has_gps=False, has_compass=False, has_camera=False,
                        has_detector=False),),
        laser_beams=30, laser_fov_deg=360.0, laser_max_range=8.0, robot_radius=0.2,
        start_region=(0.5, 0.5, 9.5, 5.5), **overrides,
    )
    obs, _ = env.reset(seed=seed)
    policy = WanderPolicy()
    policy.reset(env, seed=seed)
    xs, ys = np.meshgrid(np.arange(0.75, 9.3, 0.5), np.arange(0.75, 5.3, 0.5))
    spots = np.stack([xs.ravel(), ys.ravel()], axis=1)
    spots = spots[env.world.layout.clearance(spots) > 0.6]  # free floor, away from boxes
    spread = []
    for t in range(140):
        if t == 40:
            assert spread[-1] < 0.3  # tracking before the kidnap
            there = spots[np.argmax(np.hypot(*(spots - env.world.poses[0, :2]).T))]
            assert np.hypot(*(env.estimated_poses[0, :2] - there)) > 4.0  # far from the belief
            env.world.bodies[0].position = (float(there[0]), float(there[1]))
        obs, _, _, _, infos = env.step(policy.act(obs))
        spread.append(infos["robot_0"]["particle_spread"])
        if t == 40:
            assert np.hypot(*(env.world.poses[0, :2] - there)) < 0.5  # the robot was moved
    return max(spread[-10:]) < 0.5


def test_kidnapped_robot_is_recovered_on_the_envs_resampling_schedule():
    """The env's MCL (resampling only when the ESS falls, injecting random particles
    there) finds a kidnapped robot again; without injection it does not.

    Measured over seeds 0-39: 35 of 40 recover with the env's injection, 0 of 40
    without. Bands on seeds 0-9 (9 of 10 today): at least 7 (P(X <= 6) ~ 3 % at a
    rate of 0.875); without injection at most 1.
    """
    recovered = [_kidnap_recovered(seed) for seed in range(10)]
    assert sum(recovered) >= 7, recovered
    no_injection = {"extras": {"mcl": {"random_fraction": 0.0, "augmented": False}}}
    recovered = [_kidnap_recovered(seed, **no_injection) for seed in range(10)]
    assert sum(recovered) <= 1, recovered


def test_default_particle_count_is_1000():
    """A scenario that sets no count tracks each robot with 1000 particles (Gaussian start
    around its noisy initial estimate), and the first resampling keeps 1000."""
    env = coop_loc_env.parallel_env("outdoor_terrain", estimator="mcl", n_robots=2,
                                    max_cycles=3)
    _, infos = env.reset(seed=0)
    assert [i["n_particles"] for i in infos.values()] == [1000, 1000]
    _, _, _, _, infos = env.step({a: np.zeros(2, np.float32) for a in env.agents})
    assert [i["n_particles"] for i in infos.values()] == [1000, 1000]
