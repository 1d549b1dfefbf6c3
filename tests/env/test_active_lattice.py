"""The ``active_lattice`` family: symmetric lattices drawn per episode, its options, its
start placements and its observation (one shape for every lattice size)."""

from __future__ import annotations

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test
from scipy import ndimage

import coop_loc_env
from coop_loc_env.scenarios.active_lattice import STEPS_PER_JUNCTION
from coop_loc_env.scenarios.lattice_maps import (
    CORRIDOR,
    FRAME,
    PITCH,
    PLAZA,
    RES,
    SPUR,
    lattice_map,
    start_poses,
    world_edge,
)

FAST = {"n_particles": 200, "max_cycles": 20, "map_seed": 3}


def _plaza_mask(m, centres) -> np.ndarray:
    """Raster cells of the plazas centred at ``centres``."""
    mask = np.zeros_like(m.free)
    half = int(round(PLAZA / 2 / RES))
    for x, y in np.asarray(centres).reshape(-1, 2):
        cx, cy = int(round(x / RES)), int(round(y / RES))
        mask[cy - half:cy + half, cx - half:cx + half] = True
    return mask


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_lattice_is_symmetric_but_for_its_features(seed):
    m = lattice_map(5, 4, 1, seed)
    f = m.free
    # outside the plazas (and their turned images) a quarter turn maps the map onto itself
    feats = _plaza_mask(m, np.vstack([m.bay, m.decoys]))
    images = feats | np.rot90(feats) | np.rot90(feats, 2) | np.rot90(feats, 3)
    assert np.array_equal(np.rot90(f)[~images], f[~images])
    assert not np.array_equal(np.rot90(f), f)  # the bay (and the decoys) break it
    # a half turn maps the decoys onto each other: only the bay breaks it
    bay = _plaza_mask(m, m.bay)
    bay |= np.rot90(bay, 2)
    assert np.array_equal(np.rot90(f, 2)[~bay], f[~bay]) and not np.array_equal(np.rot90(f, 2), f)
    two = lattice_map(5, 2, 0, seed)
    bay2 = _plaza_mask(two, two.bay)
    bay2 |= np.rot90(bay2, 2)
    assert np.array_equal(np.rot90(two.free, 2)[~bay2], two.free[~bay2])
    assert len(m.decoys) == 2 and len(lattice_map(5, 4, 2, seed).decoys) == 4


def test_lattice_geometry():
    m = lattice_map(5, 4, 0, 7)
    assert world_edge(5) == FRAME == m.world and world_edge(7) == FRAME
    assert world_edge(11) > FRAME
    j = m.junctions
    steps = np.diff(np.unique(j[:, 0]))
    assert np.allclose(steps, PITCH) and len(steps) == 4
    # corridors are CORRIDOR wide: the free run across each one halfway between two
    # junctions (the bay's corridor excepted)
    runs = []
    for x, y in j:
        ix, iy = int((x + PITCH / 2) / RES), int(y / RES)
        if ix < m.free.shape[1] and m.free[iy, ix] and np.hypot(x + PITCH / 2 - m.bay[0],
                                                                 y - m.bay[1]) > PITCH / 2:
            runs.append(_run(m.free[:, ix], iy))
    assert len(runs) > 5 and set(runs) == {int(round(CORRIDOR / RES))}
    # the bay is an open square PLAZA m wide (its corridors and the block between them)
    assert _plaza_mask(m, m.bay).sum() == round(PLAZA / RES) ** 2
    assert m.free[_plaza_mask(m, m.bay)].all()
    bx, by = (m.bay / RES).astype(int)
    assert _run(m.free[by, :], bx) * RES >= PLAZA and _run(m.free[:, bx], by) * RES >= PLAZA
    # spurs end SPUR beyond the outer junctions' squares: no free cell farther out
    lo = j.min() - CORRIDOR / 2 - SPUR
    iy, ix = np.nonzero(m.free)
    assert (ix * RES).min() >= lo - 1e-9 and (iy * RES).min() >= lo - 1e-9


def _run(line: np.ndarray, at: int) -> int:
    a = b = at
    while a > 0 and line[a - 1]:
        a -= 1
    while b < len(line) - 1 and line[b + 1]:
        b += 1
    return b - a + 1


@pytest.mark.parametrize("size,symmetry,decoys", [(5, 4, 1), (7, 4, 2), (5, 2, 0)])
def test_every_free_cell_is_reachable(size, symmetry, decoys):
    for seed in range(5):
        _, count = ndimage.label(lattice_map(size, symmetry, decoys, seed).free)
        assert count == 1


def test_maps_follow_the_seed():
    a, b = lattice_map(5, 4, 1, 11), lattice_map(5, 4, 1, 12)
    assert a is lattice_map(5, 4, 1, 11)
    assert not np.array_equal(a.free, b.free) or not np.allclose(a.bay, b.bay)


def test_new_map_every_episode_unless_map_seed_is_set():
    env = coop_loc_env.parallel_env("active_lattice", n_particles=100, max_cycles=5)
    seeds = []
    for k in range(3):
        env.reset(seed=k)
        seeds.append(env.map_seed)
        # the particles live in this episode's map
        pf = env.backends[0].particle_filter(0)
        assert pf.grid is env.backends[0].particle_filter(1).grid
        assert env.config.obstacles == env.lattice.obstacles
    assert len(set(seeds)) == 3
    env.reset(seed=1)
    assert env.map_seed == seeds[1]  # the episode seed draws the map: paired episodes agree
    fixed = coop_loc_env.parallel_env("active_lattice", n_particles=100, max_cycles=5,
                                      map_seed=seeds[0])
    for k in range(2):
        fixed.reset(seed=10 + k)
        assert fixed.map_seed == seeds[0] and fixed.lattice is lattice_map(5, 4, 1, seeds[0])


@pytest.mark.parametrize("start", ["together", "scattered"])
def test_start_placements(start):
    m = lattice_map(5, 4, 1, 4)
    rng = np.random.default_rng(0)
    for _ in range(5):
        poses = start_poses(m, 4, start, 0.25, rng)
        cells = (poses[:, :2] / RES).astype(int)
        assert m.free[cells[:, 1], cells[:, 0]].all()
        gaps = np.hypot(*(poses[:, None, :2] - poses[None, :, :2]).transpose(2, 0, 1))
        assert gaps[np.triu_indices(4, 1)].min() > 0.5
        if start == "together":
            assert gaps.max() <= 6.0  # all within 3 m of one point
    spread = [np.ptp(start_poses(m, 4, "scattered", 0.25, rng)[:, :2], axis=0).max()
              for _ in range(10)]
    assert max(spread) > 6.0


@pytest.mark.parametrize("key,value", [("symmetry", 3), ("lattice_size", 2), ("decoys", -1),
                                       ("start", "apart"), ("map_seed", -4),
                                       ("lattice_size", True)])
def test_bad_options_are_refused(key, value):
    with pytest.raises(ValueError, match=key):
        coop_loc_env.make_config("active_lattice", **{key: value})


def test_decoys_need_four_fold_symmetry():
    with pytest.raises(ValueError, match="decoys"):
        coop_loc_env.make_config("active_lattice", symmetry=2, decoys=1)
    assert coop_loc_env.make_config("active_lattice", symmetry=2, decoys=0).symmetry == 2


def test_horizon_and_frame_follow_the_size():
    five = coop_loc_env.make_config("active_lattice")
    seven = coop_loc_env.make_config("active_lattice", lattice_size=7)
    assert five.max_cycles == 5 * STEPS_PER_JUNCTION and seven.max_cycles == 7 * STEPS_PER_JUNCTION
    assert five.world_size == seven.world_size == (FRAME, FRAME)


def test_one_observation_shape_for_every_size():
    shapes = []
    for size in (5, 7):
        env = coop_loc_env.parallel_env("active_lattice", obs_format="dict", lattice_size=size,
                                        **FAST)
        obs, _ = env.reset(seed=0)
        shapes.append({k: v.shape for k, v in obs["robot_0"].items()})
        assert env.observation_space("robot_0")["belief_map"].contains(obs["robot_0"]["belief_map"])
    assert shapes[0] == shapes[1]


@pytest.mark.parametrize("obs_format", ["flat", "dict"])
def test_parallel_api_both_formats(obs_format):
    parallel_api_test(coop_loc_env.parallel_env("active_lattice", obs_format=obs_format,
                                                 **FAST), num_cycles=20)


def test_env_id():
    assert coop_loc_env.env_id("active_lattice") == "coop_loc/ActiveLattice-v0"


def test_paper_profile_runs():
    from coop_loc_env.profiles import with_profile

    env = coop_loc_env.parallel_env("active_lattice",
                                    **with_profile("active_lattice", "paper", FAST))
    assert env.config.extras["mcl_detection_check"] is False
    env.reset(seed=0)
    for _ in range(3):
        env.step({a: np.array([0.5, 0.0], dtype=np.float32) for a in env.agents})


def test_belief_map_shows_each_episodes_map():
    env = coop_loc_env.parallel_env("active_lattice", obs_format="dict", n_particles=100,
                                    max_cycles=5)
    k = env.config.belief_map_headings  # the known-map channel follows the heading channels
    maps = []
    for seed in (0, 1):
        obs, _ = env.reset(seed=seed)
        maps.append(obs["robot_0"]["belief_map"][k].copy())
        free = ~np.isclose(maps[-1], 1.0)
        assert 0.1 < free.mean() < 0.6  # the lattice, inside a solid frame
    assert not np.array_equal(maps[0], maps[1])


def test_an_episode_does_not_depend_on_the_episodes_before():
    def first_steps(env, seed):
        env.reset(seed=seed)
        for _ in range(3):
            env.step({a: np.array([0.6, 0.2], dtype=np.float32) for a in env.agents})
        return env.map_seed, env.world.poses.copy(), env.estimated_poses.copy()

    fresh = first_steps(coop_loc_env.parallel_env("active_lattice", n_particles=100), 2)
    used = coop_loc_env.parallel_env("active_lattice", n_particles=100)
    first_steps(used, 0)
    again = first_steps(used, 2)
    assert fresh[0] == again[0]
    assert np.array_equal(fresh[1], again[1]) and np.array_equal(fresh[2], again[2])
