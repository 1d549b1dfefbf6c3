"""Reproduction profiles: the papers' own methods beside the project's defaults."""

from __future__ import annotations

import math

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.backends import mcl as mcl_backend
from coop_loc_env.backends.mcl import MCLBackend
from coop_loc_env.profiles import PAPER_OVERRIDES, PROFILES, with_profile


def test_default_profile_leaves_the_overrides_alone():
    assert PROFILES == ("default", "paper")
    assert with_profile("circuit", "default", {"n_robots": 3}) == {"n_robots": 3}
    with pytest.raises(ValueError, match="profile"):
        with_profile("circuit", "papers")
    with pytest.raises(ValueError, match="no paper profile"):
        with_profile("outdoor_terrain", "paper")


@pytest.mark.parametrize("scenario", sorted(PAPER_OVERRIDES))
def test_paper_profiles_make_valid_configs(scenario):
    cfg = coop_loc_env.make_config(scenario, **with_profile(scenario, "paper"))
    for key, value in PAPER_OVERRIDES[scenario].items():
        if key != "extras":
            assert getattr(cfg, key) == value, key


def test_fox_paper_profile():
    base = coop_loc_env.make_config("symmetric_hallway")
    cfg = coop_loc_env.make_config("symmetric_hallway", **with_profile(
        "symmetric_hallway", "paper", {"extras": {"mcl_resolution": 0.5}}))
    # The paper reports mean absolute errors: sigma * sqrt(2 / pi).
    assert cfg.detection_range_std * math.sqrt(2 / math.pi) == pytest.approx(0.483)
    assert math.degrees(cfg.detection_bearing_std) * math.sqrt(2 / math.pi) == pytest.approx(2.2)
    assert cfg.detector_rate == 1.0 and cfg.false_positive_prob == 0.0
    assert not cfg.detection_orientation
    ex = cfg.extras
    assert ex["mcl_detection_reset"] == 0.0 and ex["mcl_random_every_step"]
    assert ex["mcl_resolution"] == 0.5  # the user's extras win
    # the scenario's other MCL settings are kept, augmented MCL switched off
    assert ex["mcl"] == {**base.extras["mcl"], "augmented": False}


def test_random_particles_after_every_step(monkeypatch):
    calls = []
    original = mcl_backend.resample_team  # the backend resamples its team at once

    def counting(team, w, which):
        calls.extend([1] * sum(which))  # one per filter resampled
        return original(team, w, which)

    monkeypatch.setattr(mcl_backend, "resample_team", counting)
    counts = {}
    for every in (False, True):
        calls.clear()
        env = coop_loc_env.parallel_env("symmetric_hallway", n_robots=2, n_particles=200,
                                        extras={"mcl_random_every_step": every})
        env.reset(seed=0)
        assert isinstance(env.backends[0], MCLBackend)
        for _ in range(3):
            env.step({a: np.array([0.5, 0.0], dtype=np.float32) for a in env.agents})
        counts[every] = len(calls)
    assert counts[True] == 3 * 2 and counts[False] < counts[True]
