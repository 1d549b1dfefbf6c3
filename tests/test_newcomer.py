"""What a new user relies on: keywords that mean what they say, actions checked when given,
clear messages on misuse."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env import RobotSpec


# ---------------------------------------------------------------- estimator keyword
@pytest.mark.parametrize("scenario", ["symmetric_hallway", "hexagon", "circuit"])
def test_estimator_keyword_overrides_the_scenario_team(scenario):
    cfg = coop_loc_env.make_config(scenario, estimator="ekf")
    assert cfg.estimator == "ekf"
    assert set(cfg.estimators) == {"ekf"}


def test_symmetric_hallway_runs_the_ekf_when_asked():
    env = coop_loc_env.parallel_env("symmetric_hallway", estimator="ekf", n_robots=2,
                                    max_cycles=3)
    env.reset(seed=0)
    assert [type(b).__name__ for b in env.backends] == ["EKFBackend"]
    _, _, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    assert "particle_spread" not in infos["robot_0"]  # an MCL-only info
    assert env.config.estimators == ("ekf", "ekf")


def test_scenario_default_estimator_is_kept_without_the_keyword():
    cfg = coop_loc_env.make_config("symmetric_hallway")
    assert set(cfg.estimators) == {"mcl"}


def test_an_explicit_team_keeps_its_per_robot_estimators():
    team = (RobotSpec(estimator="mcl"), RobotSpec())
    cfg = coop_loc_env.make_config("outdoor_terrain", estimator="ekf", team=team, n_robots=4)
    assert cfg.estimators == ("mcl", "ekf", "mcl", "ekf")
