"""The bay-oracle reference (``scripts/bench/bay_oracle.py``): it turns only the robots that
face the long way round to the bay, and refuses bad input with exit status 2."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np

import coop_loc_env

ROOT = Path(__file__).resolve().parents[2]


def _module():
    path = ROOT / "scripts" / "bench" / "bay_oracle.py"
    spec = importlib.util.spec_from_file_location("bay_oracle", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_oracle_turns_only_the_robots_facing_the_long_way():
    oracle = _module()
    poses = np.array([[10.0, 1.25, 0.0],  # south corridor heading east: counter-clockwise
                      [10.0, 1.25, math.pi]])  # heading west: clockwise
    env = coop_loc_env.parallel_env("active_hallway", n_robots=2, n_particles=100,
                                    start_poses=tuple(map(tuple, poses)))
    obs, _ = env.reset(seed=0)
    # the bay straight north of the start on the west side: from (10, 1.25) the clockwise way
    # (west, then north) is shorter than counter-clockwise (east, north, west)
    policy = oracle.BayOraclePolicy(bay=(4.5, 10.0))
    policy.reset(env, seed=0)
    assert policy.turning[0] > 0 and policy.turning[1] == 0
    actions = policy.act(obs)
    assert actions["robot_0"][0] == 0.0 and actions["robot_0"][1] == 1.0  # turning in place
    assert actions["robot_1"][0] > 0  # already the short way: drives on
    env.close()


def test_bad_bay_exits_2(capsys):
    assert _module().main(["--bay", "1,2,3", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--bay" in err[0]
