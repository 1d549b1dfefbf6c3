"""``infogain`` for MCL robots: expected entropy over pose hypotheses (infogain_mcl)."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from estimators.mcl.beam_table import beam_lut, range_table
from estimators.mcl.occupancy import OccupancyGrid
from policies.learning.loader import make_policy
from policies.scripted import InfoGainPolicy
from policies.scripted.infogain_mcl import MCLInfoGainPlanner
from policies.scripted.infogain_scoring import (
    Primitive,
    PrimitiveScorer,
    ScanModel,
    belief_hypotheses,
)

RES = 0.25


def _corridor_model() -> ScanModel:
    """A closed 30 m x 2 m corridor with a 2 m deep alcove above x in [25, 27]; 3 m range."""
    nx, ny = int(30 / RES), int(4 / RES)
    occ = np.ones((ny, nx), dtype=bool)
    occ[: int(2 / RES)] = False  # the corridor, y in [0, 2]
    occ[:, int(25 / RES): int(27 / RES)] = False  # the alcove, y in [2, 4]
    grid = OccupancyGrid(occ, RES)
    table = range_table(grid, 3.0, n_bins=64)
    lut = beam_lut(3.0, 1.0, 0.7, 0.1, 0.1, 0.1, 0.5, 1.0)
    angles = -np.pi + (np.arange(8) + 0.5) * np.pi / 4
    return ScanModel(table, lut, angles, scans_per_s=2.0, max_speed=1.0, max_turn_rate=1.0)


def test_expected_entropy_prefers_the_motion_that_tells_two_modes_apart():
    """Two poses the corridor's half-turn symmetry makes look alike: at x = 7 facing +x and
    at x = 23 facing -x. Driving on keeps them alike (the alcove stays behind the second);
    turning round brings the second under the alcove, which tells them apart."""
    model = _corridor_model()
    poses = np.array([[7.0, 1.0, 0.0], [23.0, 1.0, np.pi]])
    weights = np.array([0.5, 0.5])
    stand, straight, back = Primitive(speed=0.0), Primitive(), Primitive(turn=np.pi)
    scorer = PrimitiveScorer(horizon=6.0, scan_every=1.0)
    out = scorer.scores(model, poses, weights, (stand, straight, back))
    ent = out["entropy"]
    assert ent[0] > 0.6 and ent[1] > 0.6  # ln 2 = 0.69: no evidence either way
    assert ent[2] < 0.3
    assert int(np.argmin(out["score"])) == 2
    assert np.all(out["collision"] == 0.0)
    assert out["progress"][0] == 0.0 and out["progress"][1] > 5.0
    # with one mode only there is nothing to learn: forward progress decides
    one = scorer.scores(model, poses[:1], np.ones(1), (stand, straight, back))
    assert np.allclose(one["entropy"], 0.0) and int(np.argmin(one["score"])) == 1
    # two hypotheses half a metre apart lie in one region: telling them apart is no gain,
    # unless the entropy is taken over the hypotheses themselves
    close = np.array([[7.0, 1.0, 0.0], [7.5, 1.0, 0.0]])
    assert np.allclose(scorer.scores(model, close, weights, (straight,))["entropy"], 0.0)
    fine = PrimitiveScorer(horizon=6.0, scan_every=1.0, region=0.0)
    assert fine.scores(model, close, weights, (straight,))["entropy"][0] > 0.0


def test_a_teammate_ahead_informs_by_detection():
    """A confident teammate near where one mode would drive: if that mode is the truth, a
    detection confirms it (an absent detection is no evidence, as in the filter), so the
    expected entropy halves: 0.5 * ~0 + 0.5 * ln 2."""
    model = _corridor_model()
    poses = np.array([[7.0, 1.0, 0.0], [23.0, 1.0, np.pi]])
    weights = np.array([0.5, 0.5])
    scorer = PrimitiveScorer(horizon=4.0)
    straight = (Primitive(),)
    alone = scorer.scores(model, poses, weights, straight)["entropy"][0]
    met = scorer.scores(model, poses, weights, straight, teammates=np.array([[11.0, 1.0]]),
                        reach=2.0)["entropy"][0]
    assert alone > 0.6 and 0.3 < met < 0.4


def test_a_confident_robot_seeks_where_a_lost_teammate_likely_is():
    """The lost teammate is at x = 12 (weight 0.8) or x = 3 (0.2), with entropy 0.5 nats:
    meeting it is worth 0.8 * 0.5 ahead and 0.2 * 0.5 behind."""
    model = _corridor_model()
    scorer = PrimitiveScorer(horizon=6.0)
    prims = (Primitive(), Primitive(turn=np.pi))
    seek = (np.array([[12.0, 1.0], [3.0, 1.0]]), 0.5 * np.array([0.8, 0.2]))
    out = scorer.scores(model, np.array([[7.0, 1.0, 0.0]]), np.ones(1), prims, reach=2.0,
                        seek=seek)
    np.testing.assert_allclose(out["team"], [0.4, 0.1])
    assert int(np.argmin(out["score"])) == 0
    seek = (seek[0], seek[1][::-1])  # now more likely behind: worth turning round
    out = scorer.scores(model, np.array([[7.0, 1.0, 0.0]]), np.ones(1), prims, reach=2.0,
                        seek=seek)
    assert int(np.argmin(out["score"])) == 1


def test_walls_stop_hypotheses_and_count_as_collisions():
    model = _corridor_model()
    scorer = PrimitiveScorer(horizon=3.0, collision_cost=1.0)
    # facing the corridor's end 1.5 m away, with the reflex unable to turn in time at 0.5 m
    out = scorer.scores(model, np.array([[28.5, 1.0, 0.0]]), np.ones(1), (Primitive(),))
    assert out["progress"][0] < 1.5
    turned = scorer.scores(model, np.array([[20.0, 1.0, np.pi / 2]]), np.ones(1),
                           (Primitive(speed=1.0),))
    assert turned["collision"][0] == 0.0  # the tracker's reflex turns it along the corridor


def test_belief_hypotheses_follow_the_modes():
    rng = np.random.default_rng(0)
    a = np.column_stack([rng.normal(2.0, 0.1, 300), rng.normal(2.0, 0.1, 300),
                         rng.normal(0.0, 0.05, 300)])
    b = np.column_stack([rng.normal(8.0, 0.1, 100), rng.normal(5.0, 0.1, 100),
                         rng.normal(np.pi / 2, 0.05, 100)])
    poses, w = belief_hypotheses(np.vstack([a, b]), np.ones(400), n=40, cell=1.0)
    near_a = np.hypot(poses[:, 0] - 2, poses[:, 1] - 2) < 1.0
    near_b = np.hypot(poses[:, 0] - 8, poses[:, 1] - 5) < 1.0
    assert np.all(near_a | near_b)
    assert w[near_a].sum() == pytest.approx(0.75, abs=0.03)
    assert w.sum() == pytest.approx(1.0)
    # deterministic: the same belief gives the same hypotheses
    again, w2 = belief_hypotheses(np.vstack([a, b]), np.ones(400), n=40, cell=1.0)
    assert np.array_equal(poses, again) and np.array_equal(w, w2)
    few, wf = belief_hypotheses(np.vstack([a, b]), np.ones(400), n=3)
    assert len(few) <= 3 and wf.sum() == pytest.approx(1.0)


def test_bad_inputs_name_the_value():
    with pytest.raises(ValueError, match="horizon"):
        PrimitiveScorer(horizon=0.0)
    with pytest.raises(ValueError, match="scan_every"):
        PrimitiveScorer(horizon=2.0, scan_every=3.0)
    with pytest.raises(ValueError, match="progress"):
        PrimitiveScorer(progress="speed")
    with pytest.raises(ValueError, match="region_headings"):
        PrimitiveScorer(region_headings=0)
    with pytest.raises(ValueError, match="n_hypotheses"):
        MCLInfoGainPlanner(n_hypotheses=0)
    with pytest.raises(ValueError, match="plan_sigma"):
        MCLInfoGainPlanner(plan_sigma=-1.0)
    with pytest.raises(ValueError, match="primitives"):
        MCLInfoGainPlanner(primitives=())
    with pytest.raises(ValueError, match="seek_weight"):
        MCLInfoGainPlanner(seek_weight=float("nan"))
    with pytest.raises(ValueError, match="straight_bonus"):
        MCLInfoGainPlanner(straight_bonus=-0.1)
    with pytest.raises(ValueError, match="side_guard"):
        MCLInfoGainPlanner(side_guard=float("inf"))
    with pytest.raises(ValueError, match="weights"):
        belief_hypotheses(np.zeros((3, 3)), np.array([1.0, -1.0, 1.0]), 4)
    with pytest.raises(ValueError, match="particles"):
        belief_hypotheses(np.zeros((3, 2)), np.ones(3), 4)
    with pytest.raises(ValueError, match="mcl"):
        InfoGainPolicy(mcl="fast")
    model = _corridor_model()
    with pytest.raises(ValueError, match="weights"):
        PrimitiveScorer().scores(model, np.zeros((2, 3)), np.array([0.2, 0.2]), (Primitive(),))


def test_infogain_on_mcl_never_reads_the_truth_and_drives(actions_with_shifted_truth):
    """Shifting the true poses before ``act`` (at replans) leaves the MCL robots' actions
    unchanged; the team drives (the planner is not idle)."""
    env = coop_loc_env.parallel_env("active_hallway", max_cycles=20)
    policy = make_policy("infogain")
    obs, _ = env.reset(seed=2)
    policy.reset(env, seed=2)
    rng = np.random.default_rng(0)
    speeds = []
    for t in range(13):
        if t % 4 == 0:  # the MCL planner replans on these steps
            before, after = actions_with_shifted_truth(env, policy, obs, rng)
            for a in env.agents:
                np.testing.assert_array_equal(before[a], after[a])
        actions = policy.act(obs)
        assert set(actions) == set(env.agents)
        speeds.append(max(float(v[0]) for v in actions.values()))
        obs, *_ = env.step(actions)
    assert max(speeds) > 0.5
    # the planner predicts scans with the filter's own tables
    backend = env.backends[0]
    table, lut, angles, rmax = backend.beam_model(1)
    assert rmax == env.config.sonar_max_range and len(angles) == env.config.sonar_beams
    own = backend.filters[1].beam_tables(rmax, table.cone_half_width)
    assert own[0] is table and own[1] is lut
