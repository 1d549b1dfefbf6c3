"""Team sizes that cannot be simulated or placed are refused at once, naming the limit."""

import time

import pytest

import coop_loc_env
from coop_loc_env.config import MAX_ROBOTS


def test_huge_team_is_refused_fast_with_the_limit():
    start = time.perf_counter()
    with pytest.raises(ValueError, match=rf"n_robots must be <= {MAX_ROBOTS}.*1000000"):
        coop_loc_env.parallel_env("outdoor_terrain", n_robots=10**6)
    assert time.perf_counter() - start < 1.0


def test_team_that_cannot_fit_in_the_start_region_is_refused():
    cfg = coop_loc_env.make_config("outdoor_terrain")
    limit = cfg.start_capacity()
    assert cfg.n_robots < limit < MAX_ROBOTS
    with pytest.raises(ValueError, match=rf"n_robots={limit + 1} .*at most {limit} fit"):
        coop_loc_env.parallel_env("outdoor_terrain", n_robots=limit + 1)
    # Given start poses, the start region does not limit the team.
    poses = tuple((1.0 + (i % 30), 1.0 + i // 30 * 1.0, 0.0) for i in range(limit + 1))
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=limit + 1, start_poses=poses,
                                    steep_patches=0, n_random_trees=0, n_random_rocks=0)
    assert env.config.n_robots == limit + 1


def test_capacity_is_an_upper_bound_on_what_placement_fits():
    # A 3 m square start region: what random placement fits never exceeds the bound.
    cfg = coop_loc_env.make_config("outdoor_terrain", start_region=(4.0, 4.0, 7.0, 7.0))
    limit = cfg.start_capacity()
    placed = 0
    for n in range(1, limit + 1):
        env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=n,
                                        start_region=(4.0, 4.0, 7.0, 7.0))
        try:
            env.reset(seed=0)
        except ValueError:
            break
        placed = n
    assert 1 <= placed <= limit
