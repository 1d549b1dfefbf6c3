"""Decisions of the scripted planners on each side of their thresholds.

Each test builds a situation whose answer flips at a threshold placed just past
the planner's default (within 5 % of it), so that moving the default by 10 %
changes the decision the test expects. (The planners' whole action sequences on
fixed seeds are pinned by the golden rollouts' ``plan_*`` cases.)
"""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from policies.scripted.corridor import follow
from policies.scripted.hypothesis import HypothesisPolicy
from policies.scripted.view import ScanView

# ---------------------------------------------------------------- hypothesis: the target


@pytest.fixture(scope="module")
def hallway():
    env = coop_loc_env.parallel_env("active_hallway", n_particles=300, max_cycles=40)
    env.reset(seed=3)
    return env


LEAD = (3.0, 1.25, 0.0)  # robot 0's lead mode: the bottom corridor, facing east


def _planned(env, policy: HypothesisPolicy, gain_of, lead: np.ndarray, keep_target=None):
    """The target ``policy._plan`` picks for robot 0 with lead pose ``lead`` when the
    information gain of each candidate is ``gain_of(cand)`` (two modes, so it asks)."""
    policy.reset(env, seed=3)
    st = policy.state[0]
    st.lead = lead
    if keep_target is not None:
        st.target = keep_target.copy()
    poses = np.array([lead, lead + [0.0, 0.0, np.pi]])
    policy._gain = lambda i, lead, poses, w, cand: gain_of(cand)
    policy._plan(0, st, poses, np.array([0.6, 0.4]), [], keep=keep_target is not None)
    return st.target


def _costs(env, policy: HypothesisPolicy, lead: np.ndarray):
    """Candidates and their cost ``path + turn_cost * turn`` from ``lead`` (the planner's)."""
    policy.reset(env, seed=3)
    plan = policy.plans[0]
    cand = plan.centres[plan.free_index]
    dist, _ = plan.distances(int(plan.cell_of(lead[:2])))
    d = cand - lead[:2]
    turn = np.abs(np.angle(np.exp(1j * (np.arctan2(d[:, 1], d[:, 0]) - lead[2]))))
    return cand, dist[plan.free_index] + policy.turn_cost * turn


def _near_and_far(env, policy, lead):
    """A candidate about 4 m and one about 24 m of cost away (both reachable)."""
    cand, cost = _costs(env, policy, lead)
    ok = np.isfinite(cost)
    near = int(np.argmin(np.where(ok, np.abs(cost - 4.0), np.inf)))
    far = int(np.argmin(np.where(ok, np.abs(cost - 24.0), np.inf)))
    assert 15.0 < cost[far] - cost[near] < 25.0
    return cand, cost, near, far


@pytest.mark.parametrize("cost_weight, picks", [(None, "far"), (0.0095, "far"),
                                                (0.0105 * 1.02, "near"), (0.011, "near")])
def test_hypothesis_cost_weight_trades_gain_for_path(hallway, cost_weight, picks):
    """Gains chosen so that the far target wins while ``cost_weight`` is below 0.0105 (the
    default 0.01 is 5 % below): a gain of 0.5 near, 0.5 + 0.0105 x the extra cost far."""
    lead = np.array(LEAD)
    policy = HypothesisPolicy(**({} if cost_weight is None else {"cost_weight": cost_weight}))
    cand, cost, near, far = _near_and_far(hallway, policy, lead)
    gains = {near: 0.5, far: 0.5 + 0.0105 * (cost[far] - cost[near])}

    def gain_of(c):
        g = np.zeros(len(c))
        for k, v in gains.items():
            g[k] = v
        return g

    target = _planned(hallway, policy, gain_of, lead)
    want = cand[far] if picks == "far" else cand[near]
    np.testing.assert_array_equal(target, want)


@pytest.mark.parametrize("extra, switches", [(0.0475, False), (0.0525, True)])
def test_hypothesis_keeps_its_target_unless_another_beats_it_by_switch_margin(
        hallway, extra, switches):
    """At a periodic replan a target 5 % less than ``switch_margin`` (0.05) better is not
    worth switching to, one 5 % more is."""
    lead = np.array(LEAD)
    policy = HypothesisPolicy()
    cand, cost, near, far = _near_and_far(hallway, policy, lead)
    cw = policy.cost_weight
    gains = np.zeros(len(cand))
    gains[near] = 0.5
    gains[far] = 0.5 + cw * (cost[far] - cost[near]) + extra  # far's utility: near's + extra
    target = _planned(hallway, policy, lambda c: gains, lead, keep_target=cand[near])
    np.testing.assert_array_equal(target, cand[far] if switches else cand[near])


# ---------------------------------------------------------------- corridor: follow the scan
def _scan(front: float = 6.0, left: float = 2.0, right: float = 2.0,
          extra: dict[float, float] | None = None, elsewhere: float = 5.0) -> ScanView:
    """A 360-degree scan of 72 beams (one straight ahead): ``front`` within 0.4 rad of
    ahead, ``left`` and ``right`` in the side sectors, ``elsewhere`` in the rest; ``extra``
    sets single beams by angle."""
    angles = np.linspace(-np.pi, np.pi, 72, endpoint=False)
    ranges = np.full(72, elsewhere)
    ranges[np.abs(angles) <= 0.4] = front
    ranges[(angles >= 1.2) & (angles <= 1.95)] = left
    ranges[(angles <= -1.2) & (angles >= -1.95)] = right
    for angle, r in (extra or {}).items():
        ranges[int(np.argmin(np.abs(angles - angle)))] = r
    return ScanView(ranges, angles, 8.0)


@pytest.mark.parametrize("front, turns", [(0.57, True), (0.63, False)])
def test_corridor_turns_in_place_when_something_is_close_ahead(front, turns):
    """Nearer than 0.6 m ahead: turn in place toward the freer side."""
    act = follow(_scan(front=front, left=3.0, right=2.0))
    if turns:
        np.testing.assert_array_equal(act, np.float32([0.0, 0.8]))
    else:
        assert act[0] > 0.0


@pytest.mark.parametrize("front", [1.0, 1.9, 2.1])
def test_corridor_slows_down_linearly_within_two_metres(front):
    act = follow(_scan(front=front, left=front, right=front, elsewhere=front))
    assert act[0] == pytest.approx(min(1.0, front / 2.0), rel=1e-6)
    assert act[1] == 0.0


@pytest.mark.parametrize("steers", [False, True])
def test_corridor_turn_penalty_decides_between_ahead_and_a_freer_side(steers):
    """A beam 0.52 rad to the left wins over the 6 m ahead when it is longer by more than
    0.8 m per radian off the heading."""
    angles = np.linspace(-np.pi, np.pi, 72, endpoint=False)
    b = float(angles[int(np.argmin(np.abs(angles - 0.5)))])
    scan = _scan(front=6.0, extra={b: 6.0 + 0.8 * b * (0.95 if not steers else 1.05)})
    act = follow(scan)
    assert (act[1] > 0.5) == steers
    if not steers:
        assert act[1] == 0.0


def test_corridor_steers_away_from_the_nearer_wall():
    """Half a radian of steering per metre of side clearance difference, times the gain 3."""
    act = follow(_scan(left=2.4, right=2.0))
    assert act[1] == pytest.approx(3.0 * 0.5 * 0.4, rel=1e-6)
