"""Tests of the weights given to the symmetric copies of a belief's top mode."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coop_loc_env import belief_map
from estimators.mcl.copy_weights import (
    TOP_MODE_HEADING_TOL,
    hypothesis_shares,
    near_pose,
    set_group_masses,
    top_mode,
)


def test_shares_follow_the_evidence_with_equal_priors():
    np.testing.assert_allclose(hypothesis_shares(np.array([-4.0, -4.0, -4.0])), [1 / 3] * 3)
    np.testing.assert_allclose(hypothesis_shares(np.array([math.log(3.0), 0.0])), [0.75, 0.25])
    # far apart log-likelihoods stay finite
    np.testing.assert_allclose(hypothesis_shares(np.array([0.0, -800.0])), [1.0, 0.0])
    with pytest.raises(ValueError, match="loglik"):
        hypothesis_shares(np.array([0.0, np.nan]))


def test_the_top_mode_is_extracted_as_the_observation_does():
    assert TOP_MODE_HEADING_TOL == belief_map.MODE_HEADING_TOL
    rng = np.random.default_rng(0)
    poses = np.concatenate([rng.normal([4.0, 4.0, 0.5], [0.2, 0.2, 0.05], (600, 3)),
                            rng.normal([14.0, 9.0, -2.0], [0.2, 0.2, 0.05], (400, 3))])
    pose, weight = top_mode(poses, np.full(1000, 1e-3), 2.0, TOP_MODE_HEADING_TOL,
                            (0.0, 0.0, 20.0, 20.0))
    assert weight == pytest.approx(0.6, abs=0.01)
    np.testing.assert_allclose(pose, [4.0, 4.0, 0.5], atol=0.05)
    near = near_pose(poses, pose, 2.0, TOP_MODE_HEADING_TOL)
    assert near[:600].mean() > 0.99 and not near[600:].any()
    # a particle at the right place but turned beyond the tolerance is not in the mode
    assert not near_pose(np.array([[4.0, 4.0, 0.5 + 1.0]]), pose, 2.0, TOP_MODE_HEADING_TOL)[0]


def test_group_masses_are_set_and_a_starved_copy_is_refilled():
    rng = np.random.default_rng(1)
    mode = rng.normal([4.0, 4.0, 0.0], [0.2, 0.2, 0.02], (900, 3))
    stray = rng.uniform([8.0, 8.0, -3.0], [12.0, 12.0, 3.0], (100, 3))  # outside both
    parts = np.concatenate([mode, stray])
    w = np.concatenate([np.full(900, 0.9 / 900), np.full(100, 0.1 / 100)])
    w[900:910] *= 0.01  # the least likely particles give their slots
    copy = mode + [12.0, 12.0, 0.0]  # a copy of the mode that holds no particle
    centres = np.array([[4.0, 4.0], [16.0, 16.0]])
    out, new_w, placed = set_group_masses(parts, w, centres, [mode, copy],
                                          np.array([0.45, 0.45]), 2.0, rng)
    at_copy = np.hypot(*(out[:, :2] - centres[1]).T) <= 2.0
    at_mode = np.hypot(*(out[:, :2] - centres[0]).T) <= 2.0
    # 0.45 N particles: the 100 outside first, then the mode's least likely beyond its share
    assert placed == at_copy.sum() == 450 and at_mode.sum() == 550
    assert (new_w[at_mode] > 0).all()
    assert new_w.sum() == pytest.approx(1.0)
    # the group (everything but what stays outside) is shared as asked
    assert new_w[at_copy].sum() == pytest.approx(new_w[at_mode].sum(), rel=1e-9)
    # with room: only the least likely outside particles are taken, the rest keep weight
    w2 = w.copy()
    out2, new_w2, placed2 = set_group_masses(parts, w2, centres, [mode, copy],
                                             np.array([0.05, 0.01]), 2.0, rng)
    assert placed2 == 10 and set(np.nonzero((out2 != parts).any(axis=1))[0]) <= set(
        range(900, 910))
    keep = np.arange(910, 1000)
    np.testing.assert_allclose(new_w2[keep], w2[keep] / w2.sum(), rtol=1e-9)
    at_mode2 = np.hypot(*(out2[:, :2] - centres[0]).T) <= 2.0
    at_copy2 = np.hypot(*(out2[:, :2] - centres[1]).T) <= 2.0
    assert new_w2[at_mode2].sum() == pytest.approx(5 * new_w2[at_copy2].sum(), rel=1e-9)
    with pytest.raises(ValueError, match="mass"):
        set_group_masses(parts, w, centres, [mode], np.array([0.5, 0.5]), 2.0, rng)
