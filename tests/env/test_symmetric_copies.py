"""A lone robot must not report one of several map copies its sensors cannot tell apart.

Constructed in ``active_hallway`` with one robot standing still in the middle of
the bottom corridor, far from the bay that breaks the ring's symmetry: its
belief starts collapsed onto the copy of its pose turned half a turn about the
centre of the ring (the top corridor), as a filter's particles end up when
whichever copies held particles survived. Its scans fit both copies equally.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.belief_map import BeliefModesBlock, TeamBeliefs
from estimators.mcl.detection_consistency import main_mode
from estimators.mcl.map_symmetry import MapSymmetry, map_symmetries, symmetric_copies
from estimators.mcl.occupancy import OccupancyGrid

TRUE = np.array([10.0, 1.25, 0.3])  # bottom corridor, far from the bay (left corridor)
HALF_TURN = np.array([20.0 - TRUE[0], 20.0 - TRUE[1], TRUE[2] - math.pi])


def _collapsed_on_the_copy(**extras):
    # the scenario's own extras (its MCL tuning), with the given ones on top
    extras = {**coop_loc_env.make_config("active_hallway").extras, **extras}
    env = coop_loc_env.parallel_env("active_hallway", n_robots=1, cooperative_updates=False,
                                    start_poses=(tuple(TRUE),), extras=extras)
    env.reset(seed=0)
    np.testing.assert_allclose(env.world.poses[0], TRUE)
    backend = env.backends[0]
    rng = np.random.default_rng(0)
    backend.filters[0].set_particles(HALF_TURN + rng.normal(0, [0.15, 0.15, 0.03], (1000, 3)))
    return env, backend


def _calibrated() -> dict:
    """The scenario's extras with the kept copies sharing the top mode's weight."""
    return {**coop_loc_env.make_config("active_hallway").extras, "mcl_calibrated_copies": True}


def _stand_still(env, steps: int) -> dict:
    info = {}
    for _ in range(steps):
        _, _, _, _, info = env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})
    return info["robot_0"]


def test_hallway_symmetries_are_the_quarter_turns_about_the_centre():
    env = coop_loc_env.parallel_env("active_hallway", n_robots=1)
    env.reset(seed=0)
    syms = map_symmetries(env.backends[0].filters[0].grid, 0.75)
    assert sorted(round(math.degrees(s.angle)) for s in syms) == [-180, -90, 90]
    for s in syms:
        assert s.centre == pytest.approx((10.0, 10.0), abs=1e-9)
        assert 0.75 <= s.overlap < 1.0  # the bay breaks it


def test_a_map_without_symmetry_has_none():
    occ = np.zeros((40, 40), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    occ[5:12, 5:30] = True  # one off-centre block, an L-shaped nook
    occ[12:25, 5:9] = True
    assert map_symmetries(OccupancyGrid(occ, 0.25, (0.0, 0.0)), 0.75) == ()


def test_symmetric_copies_turn_positions_and_headings():
    s = MapSymmetry(math.pi / 2, (10.0, 10.0), 1.0)
    out = symmetric_copies(np.array([[12.0, 10.0, 0.0], [10.0, 13.0, 3.0]]), s)
    np.testing.assert_allclose(out, [[10.0, 12.0, math.pi / 2],
                                     [7.0, 10.0, 3.0 + math.pi / 2 - 2 * math.pi]], atol=1e-12)
    np.testing.assert_allclose(symmetric_copies(np.array([12.0, 10.0, 0.0]), s),
                               [10.0, 12.0, math.pi / 2], atol=1e-12)


@pytest.mark.parametrize("bad", [0.0, 1.5])
def test_bad_overlap_is_refused(bad):
    with pytest.raises(ValueError, match=str(bad)):
        map_symmetries(OccupancyGrid(np.zeros((4, 4), dtype=bool), 1.0), bad)


def test_a_lone_robot_on_an_indistinguishable_copy_is_not_confident():
    env, backend = _collapsed_on_the_copy()
    pf = backend.filters[0]
    _stand_still(env, 2)  # 1 s: the history the check needs
    kept = 0
    for _ in range(16):
        info = _stand_still(env, 1)
        cov = np.asarray(info["pose_cov"])
        assert info["position_error"] > 3.0  # still mostly on a wrong copy ...
        assert math.sqrt(cov[0, 0] + cov[1, 1]) > 1.0  # ... but never confident about it
        parts, w = pf.particles, pf.weights
        _, mode = main_mode(parts[:, :2], w, 2.0)
        if w[mode].sum() >= 0.8:  # while one copy dominates, the true one is kept
            near_truth = np.hypot(*(parts[:, :2] - TRUE[:2]).T) < 1.0
            assert w[near_truth].sum() >= 0.004
            kept += 1
    assert kept >= 4


def test_with_calibrated_copies_the_indistinguishable_copies_share_the_weight():
    env, backend = _collapsed_on_the_copy(mcl_calibrated_copies=True)
    pf = backend.filters[0]
    block = BeliefModesBlock(env.config)
    _stand_still(env, 2)  # 1 s: the history the check needs
    for _ in range(16):
        info = _stand_still(env, 1)
        cov = np.asarray(info["pose_cov"])
        assert info["position_error"] > 3.0  # not on the true copy alone ...
        assert math.sqrt(cov[0, 0] + cov[1, 1]) > 1.0  # ... and never confident about it
        # the copies its scans cannot tell apart share the weight: the true one holds as
        # much as the copy it had collapsed onto, and the top mode weighs what it is worth
        near_truth = np.hypot(*(pf.particles[:, :2] - TRUE[:2]).T) < 1.0
        near_copy = np.hypot(*(pf.particles[:, :2] - HALF_TURN[:2]).T) < 1.0
        assert pf.weights[near_truth].sum() >= 0.25
        assert pf.weights[near_truth].sum() == pytest.approx(pf.weights[near_copy].sum(),
                                                             abs=0.05)
        top = block.modes(TeamBeliefs.from_env(env))[0, 0, 0]
        assert top <= 0.5


def test_the_calibrated_copies_option_switches_the_keeper():
    # the same start, the same scans: the token keeper leaves the top mode (the wrong copy)
    # near 1, the calibrated one splits it with the true copy
    tops = {}
    for flag in (False, True):
        env, _ = _collapsed_on_the_copy(mcl_calibrated_copies=flag)
        block = BeliefModesBlock(env.config)
        _stand_still(env, 6)
        tops[flag] = block.modes(TeamBeliefs.from_env(env))[0, 0, 0]
    assert tops[False] > 0.9 and tops[True] <= 0.5


def test_calibrated_copies_flag_is_validated():
    with pytest.raises(ValueError, match="mcl_calibrated_copies"):
        coop_loc_env.make_config("active_hallway", extras={"mcl_calibrated_copies": "yes"})


def test_without_the_check_the_copy_stays_confident():
    # Fox et al.'s filter alone (the paper profile's setting) keeps the wrong copy sharply
    env, _ = _collapsed_on_the_copy(mcl_symmetry_check=False)
    info = _stand_still(env, 16)
    cov = np.asarray(info["pose_cov"])
    assert info["position_error"] > 3.0 and math.sqrt(cov[0, 0] + cov[1, 1]) < 1.0


def test_symmetry_check_flag_is_validated():
    with pytest.raises(ValueError, match="mcl_symmetry_check"):
        coop_loc_env.make_config("active_hallway", extras={"mcl_symmetry_check": 1})


def test_a_certified_robot_checked_again_keeps_what_it_saw():
    # with the calibrated copies: certified next to the bay, then 40 s along the ring, its
    # last 30 s of scans no longer tell the copies apart. A conflicting detection (most are
    # false positives) has it checked again; it must not split its weight over the copies
    # it had ruled out.
    from policies.scripted.corridor import CorridorPolicy

    start = (1.25, 10.0, math.pi / 2)  # the left corridor, beside the bay
    env = coop_loc_env.parallel_env("active_hallway", n_robots=1, cooperative_updates=False,
                                     start_poses=(start,), extras=_calibrated())
    obs, _ = env.reset(seed=0)
    backend = env.backends[0]
    rng = np.random.default_rng(0)
    backend.filters[0].set_particles(np.array(start) + rng.normal(0, [0.1, 0.1, 0.02],
                                                                  (1000, 3)))
    policy = CorridorPolicy(1.0)
    policy.reset(env, seed=0)
    block = BeliefModesBlock(env.config)
    for _ in range(80):
        obs, *_ = env.step(policy.act(obs))
    assert backend._certified[0]
    assert np.hypot(*(env.world.poses[0, :2] - start[:2])) > 8.0  # the bay out of range
    backend._certified[0] = False  # what a conflicting detection does
    backend._plausible[0] = None
    for _ in range(4):
        obs, _, _, _, info = env.step(policy.act(obs))
        assert block.modes(TeamBeliefs.from_env(env))[0, 0, 0] > 0.9
        assert info["robot_0"]["particle_spread"] < 1.5


def test_a_robot_told_its_start_keeps_it_in_a_symmetric_map():
    # with the calibrated copies: without global localization the start (known up to
    # noise) is evidence the scans of a symmetric corridor cannot outweigh: the copies of
    # the pose get no share
    env = coop_loc_env.parallel_env("active_hallway", n_robots=1, cooperative_updates=False,
                                    global_localization=False, start_poses=(tuple(TRUE),),
                                    extras=_calibrated())
    env.reset(seed=0)
    block = BeliefModesBlock(env.config)
    for _ in range(12):
        info = _stand_still(env, 1)
        assert block.modes(TeamBeliefs.from_env(env))[0, 0, 0] > 0.9
        assert info["particle_spread"] < 1.5
