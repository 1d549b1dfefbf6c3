"""The dict observation (obs_format="dict"): the belief's modes and the belief as a map."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import coop_loc_env
from coop_loc_env.belief_map import TeamBeliefs
from estimators.mcl.modes import particle_modes, raster_particles

FAST = {"max_cycles": 12, "n_particles": 200}


def _drive(env, steps: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    obs = None
    for _ in range(steps):
        obs, *_ = env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
    return obs


@pytest.mark.parametrize("scenario", coop_loc_env.list_scenarios())
def test_parallel_api_with_dict_observation(scenario):
    parallel_api_test(coop_loc_env.parallel_env(scenario, obs_format="dict", **FAST),
                      num_cycles=12)


def test_dict_vector_starts_with_the_flat_observation_and_dynamics_are_unchanged():
    flat = coop_loc_env.parallel_env("active_hallway", max_cycles=20, n_particles=300)
    dict_ = coop_loc_env.parallel_env("active_hallway", max_cycles=20, n_particles=300,
                                      obs_format="dict")
    a, _ = flat.reset(seed=4)
    b, _ = dict_.reset(seed=4)
    rng = np.random.default_rng(1)
    size = flat.observation_space("robot_0").shape[0]
    for _ in range(15):
        for agent in flat.agents:
            np.testing.assert_array_equal(b[agent]["vector"][:size], a[agent])
        act = {ag: rng.uniform(-1, 1, 2).astype(np.float32) for ag in flat.agents}
        a, _, _, _, ia = flat.step(act)
        b, _, _, _, ib = dict_.step(act)
        for agent in flat.agents:
            np.testing.assert_array_equal(ia[agent]["true_pose"], ib[agent]["true_pose"])
            np.testing.assert_array_equal(ia[agent]["est_pose"], ib[agent]["est_pose"])
    space = dict_.observation_space("robot_0")
    assert space["vector"].shape == (size + 6 * 4,)
    assert all(space.contains(o) for o in b.values())


def test_belief_map_channels_mass_occupancy_and_team():
    env = coop_loc_env.parallel_env("active_hallway", n_particles=400, obs_format="dict")
    env.reset(seed=2)
    obs = _drive(env, 10)
    maps = np.stack([obs[a]["belief_map"] for a in env.possible_agents])
    assert maps.shape == (4, 10, 32, 32) and maps.dtype == np.float32
    np.testing.assert_allclose(maps[:, :8].sum(axis=(1, 2, 3)), 1.0, atol=1e-5)
    occ = maps[0, 8]  # 20 m / 32 cells: the inner block (6.5..17.5 m) is solid, the ring free
    assert occ[16, 20] == 1.0 and occ[16, 1] == 0.0 and occ[1, 16] == 0.0
    assert occ[16, 6] == 0.0  # the bay (x 2.5..6.5 m, y 7.5..12.5 m) is open
    np.testing.assert_array_equal(maps[:, 8], maps[:1, 8].repeat(4, 0))
    position = maps[:, :8].sum(axis=1)
    for i in range(4):
        others = position.sum(axis=0) - position[i]
        np.testing.assert_allclose(maps[i, 9], others, atol=1e-5)


def test_dict_observation_never_reads_the_true_poses():
    env = coop_loc_env.parallel_env("active_hallway", n_particles=300, obs_format="dict")
    env.reset(seed=5)
    _drive(env, 12)
    before = env._observe_all(env.agents)
    saved = env.world.poses.copy()
    env.world.poses[:, :2] += np.random.default_rng(0).uniform(-4, 4, size=(4, 2))
    env.world.poses[:, 2] += 1.0
    after = env._observe_all(env.agents)
    env.world.poses[:] = saved
    for agent in env.agents:
        for key in ("vector", "belief_map"):
            np.testing.assert_array_equal(before[agent][key], after[agent][key])


@pytest.mark.parametrize("estimator", ["ekf", "mle"])
def test_gaussian_beliefs_are_rasterized_at_their_mean(estimator):
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=3, estimator=estimator,
                                    obs_format="dict", belief_map_cells=20)
    obs, _ = env.reset(seed=1)
    mean = env.estimated_poses
    w, h = env.config.world_size
    for i, agent in enumerate(env.possible_agents):
        m = obs[agent]["belief_map"]
        mass = m[:8].sum(axis=0)
        assert mass.sum() == pytest.approx(1.0, abs=1e-5)
        iy, ix = np.unravel_index(np.argmax(mass), mass.shape)
        assert ix == int(mean[i, 0] / w * 20) and iy == int(mean[i, 1] / h * 20)
        heading_bin = int((mean[i, 2] + math.pi) / (2 * math.pi) * 8) % 8
        assert int(np.argmax(m[:8].sum(axis=(1, 2)))) == heading_bin
        modes = obs[agent]["vector"][-24:].reshape(4, 6)
        assert modes[0, 0] == 1.0 and not modes[1:].any()
        np.testing.assert_allclose(modes[0, 1:5], [mean[i, 0] / w * 2 - 1, mean[i, 1] / h * 2 - 1,
                                                   math.cos(mean[i, 2]), math.sin(mean[i, 2])],
                                   atol=1e-5)


def _block(poses: np.ndarray, weights: np.ndarray):
    flat = np.ascontiguousarray(poses.T, dtype=np.float32).ravel()
    return flat, np.asarray(weights, float), np.array([len(poses)]), np.zeros((1, 2))


def test_particle_modes_are_sorted_weighted_and_zero_padded():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.normal(3, 0.3, 300), rng.normal(4, 0.3, 300),
                         rng.normal(0.5, 0.05, 300)])
    b = np.column_stack([rng.normal(15, 0.5, 700), rng.normal(12, 0.5, 700),
                         rng.normal(-2.0, 0.05, 700)])
    poses = np.concatenate([a, b])
    w = np.concatenate([np.full(300, 0.6 / 300), np.full(700, 0.4 / 700)])
    modes = particle_modes(*_block(poses, w), 4, 2.0, math.pi / 4, (0, 0, 20, 20))[0]
    assert modes.shape == (4, 6)
    np.testing.assert_allclose(modes[:2, 0], [0.6, 0.4], atol=0.02)
    np.testing.assert_allclose(modes[0, 1:3], [3, 4], atol=0.1)
    np.testing.assert_allclose(modes[1, 1:3], [15, 12], atol=0.1)
    np.testing.assert_allclose(np.arctan2(modes[:2, 4], modes[:2, 3]), [0.5, -2.0], atol=0.02)
    assert modes[0, 5] == pytest.approx(0.3 * math.sqrt(2), rel=0.25)
    assert modes[1, 5] == pytest.approx(0.5 * math.sqrt(2), rel=0.25)
    assert modes[2:, 0].sum() < 0.01  # stragglers beyond 2 m of both seeds
    tight = np.column_stack([rng.normal(8, 0.2, 200), rng.normal(8, 0.2, 200), np.zeros(200)])
    one = particle_modes(*_block(tight, np.full(200, 1 / 200)), 4, 2.0, math.pi / 4,
                         (0, 0, 20, 20))[0]
    assert one[0, 0] == pytest.approx(1.0) and not one[1:].any()  # zero-padded


def test_raster_counts_each_particle_in_its_cell_and_heading_bin():
    poses = np.array([[0.5, 0.5, -3.0], [1.5, 0.5, 0.1], [1.6, 0.4, 0.2], [9.9, 9.9, 3.1]])
    out = raster_particles(*_block(poses, [0.1, 0.2, 0.3, 0.4]), 0.0, 0.0, 1.0, 1.0, 10, 10, 4)
    assert out.shape == (1, 4, 10, 10)
    assert out[0, 0, 0, 0] == pytest.approx(0.1)  # heading -3.0: bin 0 of 4
    assert out[0, 2, 0, 1] == pytest.approx(0.5)  # two particles in cell (x 1, y 0), bin 2
    assert out[0, 3, 9, 9] == pytest.approx(0.4)
    assert out.sum() == pytest.approx(1.0)


def test_team_beliefs_list_every_particle_filter():
    env = coop_loc_env.parallel_env("active_hallway", n_particles=200)
    env.reset(seed=0)
    beliefs = TeamBeliefs.from_env(env)
    (robots, flat, w, ends, org), = list(beliefs.blocks())
    assert robots.tolist() == [0, 1, 2, 3] and flat.size == 3 * int(ends[-1]) == 3 * w.size


@pytest.mark.parametrize("key, value", [("obs_format", "image"), ("belief_map_cells", 1),
                                        ("belief_map_headings", 0), ("belief_modes", 0)])
def test_bad_dict_observation_settings_raise(key, value):
    with pytest.raises(ValueError, match=key):
        coop_loc_env.make_config("active_hallway", **{key: value})
