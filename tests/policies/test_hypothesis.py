"""The ``hypothesis`` baseline: modes, where they disagree, geodesic planning, the team."""

from __future__ import annotations

import math

import numpy as np
import pytest

import coop_loc_env
from policies.learning.loader import make_policy
from policies.scripted import HypothesisPolicy
from policies.scripted.hypothesis import distinctive_cells
from policies.scripted.planning import PlanGrid
from policies.scripted.registry import policy_names


@pytest.fixture(scope="module")
def hallway():
    """An active_hallway env (reset) and a hypothesis policy bound to it."""
    env = coop_loc_env.parallel_env("active_hallway", n_particles=300, max_cycles=40)
    env.reset(seed=3)
    policy = HypothesisPolicy()
    policy.reset(env, seed=3)
    return env, policy


def _rotations(pose: tuple[float, float, float]) -> np.ndarray:
    """The four quarter-turn copies of ``pose`` about the hallway's centre (10, 10)."""
    x, y, th = pose
    out = []
    for k in range(4):
        a = k * math.pi / 2
        c, s = math.cos(a), math.sin(a)
        out.append([10 + c * (x - 10) - s * (y - 10), 10 + s * (x - 10) + c * (y - 10), th + a])
    return np.array(out)


def test_registered_and_arguments_checked():
    assert "hypothesis" in policy_names()
    assert isinstance(make_policy("hypothesis"), HypothesisPolicy)
    with pytest.raises(ValueError, match="hypothesis"):
        make_policy("hypothesis:3")
    for kw in ({"min_weight": 0.0}, {"scan_sigma": -1.0}, {"n_modes": 0}, {"meet": "always"}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            HypothesisPolicy(**kw)


def test_geodesic_distance_follows_the_corridors(hallway):
    env, policy = hallway
    plan: PlanGrid = policy.plans[0]
    a = int(plan.cell_of(np.array([1.25, 4.0])))  # left corridor, south of the bay
    b = int(plan.cell_of(np.array([18.75, 4.0])))  # right corridor: 17.5 m away in a line
    dist, _ = plan.distances(a)
    assert 20.0 < dist[b] < 30.0  # around the inner block's south side, not through it
    path = plan.path(a, b)
    assert plan.free[plan.cell_of(path)].all()
    assert path[:, 1].min() < 2.5  # by the south corridor
    assert not plan.free[int(10.0 / plan.cell) * plan.nx + int(12.0 / plan.cell)]  # the block


def test_gain_is_high_where_the_modes_see_the_bay_and_nil_at_the_corners(hallway):
    env, policy = hallway
    poses = _rotations((1.25, 5.0, math.pi / 2))  # heading north in the left corridor, and copies
    w = np.full(4, 0.25)
    cand = np.array([[1.25, 10.0], [10.0, 1.25], [1.25, 1.25], [18.75, 18.75]])
    gain = policy._gain(0, poses[0], poses, w, cand)
    # the middle of a corridor is the bay under one of the four modes: that one is told
    # apart (1 - 0.25^2 - 0.75^2 = 0.375); at a corner all four see the same
    assert gain[0] == pytest.approx(0.375, abs=0.06) and gain[1] == pytest.approx(0.375, abs=0.06)
    assert gain[2] < 0.05 and gain[3] < 0.05


def test_distinctive_cells_are_by_the_bay(hallway):
    env, policy = hallway
    plan = policy.plans[0]
    table, angles, max_range = policy.models[0]
    d = distinctive_cells(plan, table, angles, max_range)
    pts = plan.centres[plan.free_index]
    by_bay = (pts[:, 0] < 7.0) & (pts[:, 1] > 6.0) & (pts[:, 1] < 14.0)
    assert d[by_bay].max() > 1.0 and np.percentile(d[~by_bay], 90) < 0.9


def test_hypothesis_never_reads_the_truth_and_drives(actions_with_shifted_truth):
    """Shifting the true poses (nothing a robot could know) leaves the actions unchanged."""
    env = coop_loc_env.parallel_env("active_hallway", n_particles=400, max_cycles=40)
    policy = make_policy("hypothesis")
    obs, _ = env.reset(seed=2)
    policy.reset(env, seed=2)
    rng = np.random.default_rng(0)
    start = env.world.poses[:, :2].copy()
    for _ in range(30):
        before, after = actions_with_shifted_truth(env, policy, obs, rng, shift=3.0)
        assert all(np.array_equal(before[a], after[a]) for a in env.agents)
        obs, *_ = env.step(policy.act(obs))
    moved = np.hypot(*(env.world.poses[:, :2] - start).T)
    assert moved.mean() > 2.0  # it drives (net displacement after 15 s)


@pytest.mark.parametrize("scenario, spec", [("active_hallway", n) for n in policy_names()]
                         + [("outdoor_terrain", n) for n in ("fsm", "gather", "seek", "infogain")])
def test_scripted_policies_run_on_the_dict_observation(scenario, spec):
    """Every registered policy reads beliefs, scans or the vector's flat entries: it acts
    on the dict observation as on the flat one."""
    env = coop_loc_env.parallel_env(scenario, n_robots=2, n_particles=100, max_cycles=4,
                                    obs_format="dict")
    policy = make_policy(spec)
    obs, _ = env.reset(seed=0)
    policy.reset(env, seed=0)
    while env.agents:
        act = policy.act(obs)
        assert set(act) == set(env.agents)
        assert all(np.all(np.abs(a) <= 1) for a in act.values())
        obs, *_ = env.step(act)
