"""The compiled range-table builder equals the vectorized one, and a known centre of
symmetry gives the symmetries the search finds."""

from __future__ import annotations

import numpy as np

import coop_loc_env
from coop_loc_env.backends.mcl import SYMMETRY_OVERLAP, known_map
from estimators.mcl import beam_table
from estimators.mcl.map_symmetry import _find, seed_symmetries
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.range_cast import build_range_table, prepare_range_table


def _lattice_grid(seed: int = 5) -> OccupancyGrid:
    env = coop_loc_env.parallel_env("active_lattice", n_particles=50, map_seed=seed)
    return known_map(env.world, "sonar", 0.25)


def test_compiled_table_equals_the_vectorized_one():
    grid = _lattice_grid()
    cone = 0.5 * np.deg2rad(360.0) / 16
    fast = build_range_table(grid, 6.0, 256, cone, 3)
    slow = beam_table._build(grid, 6.0, 256, cone, 3)
    assert np.array_equal(fast.rows, slow.rows)
    assert np.array_equal(fast.scales, slow.scales) and fast.origin == slow.origin
    assert (fast.cone_half_width, fast.rays_per_cone) == (slow.cone_half_width, slow.rays_per_cone)


def test_small_grid_without_cone_and_off_bin_cones():
    occ = np.zeros((12, 14), dtype=bool)
    occ[5:7, 3:9] = True
    grid = OccupancyGrid(occ, 0.5, (0.0, 0.0))
    fast = build_range_table(grid, 4.0, 64)
    slow = beam_table._build(grid, 4.0, 64, 0.0, 1)
    # a range may differ by one quantum (max_range / 32767 m) from float rounding
    diff = np.abs(fast.rows.astype(int) - slow.rows.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 0.01
    # rays off the bin centres: left to range_table
    assert build_range_table(grid, 4.0, 64, 0.05, 3) is None
    assert prepare_range_table(grid, 4.0, 64, 0.05, 3) is False


def test_prepared_table_is_the_one_range_table_returns():
    occ = np.zeros((10, 10), dtype=bool)
    occ[4, 2:8] = True
    grid = OccupancyGrid(occ, 0.5, (0.0, 0.0))
    assert prepare_range_table(grid, 3.0, 32, 0.0, 1)
    built = beam_table.range_table(grid, 3.0, 32)
    assert np.array_equal(built.rows, beam_table._build(grid, 3.0, 32, 0.0, 1).rows)


def test_known_centre_gives_the_searched_symmetries():
    grid = _lattice_grid(2)
    searched = _find(grid, SYMMETRY_OVERLAP)
    seeded = seed_symmetries(grid, (20.0, 20.0), SYMMETRY_OVERLAP)
    assert [round(s.angle, 6) for s in seeded] == [round(s.angle, 6) for s in searched]
    assert len(seeded) == 3  # quarter, half and three-quarter turns
    for a, b in zip(seeded, searched, strict=True):
        assert np.allclose(a.centre, b.centre) and abs(a.overlap - b.overlap) < 1e-9
