"""What a new user relies on: keywords that mean what they say, actions checked when given,
clear messages on misuse."""

from __future__ import annotations

from pathlib import Path

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


# ---------------------------------------------------------------- actions
def _env(**kw):
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, max_cycles=5, **kw)
    env.reset(seed=0)
    return env


@pytest.mark.parametrize(
    "bad",
    [
        np.array(["0.5", "-0.2"]),
        np.array([True, False]),
        [True, 0.1],
        ["0.5", "-0.2"],
        np.array([0.5 + 0j, 0.1]),
        True,
        0.5,
    ],
    ids=["str-array", "bool-array", "bool-in-list", "str-list", "complex", "bool", "scalar"],
)
def test_parallel_env_refuses_non_numeric_actions(bad):
    env = _env()
    with pytest.raises(ValueError, match="robot_1"):
        env.step({"robot_0": np.zeros(2), "robot_1": bad})
    env.step({"robot_0": np.zeros(2), "robot_1": np.zeros(2)})  # still usable


def test_list_and_tuple_actions_are_accepted_like_arrays():
    a, b = _env(), _env()
    obs_a = a.step({"robot_0": [0.5, -0.2], "robot_1": (1, 0)})[0]
    obs_b = b.step({"robot_0": np.array([0.5, -0.2]), "robot_1": np.array([1.0, 0.0])})[0]
    for agent in obs_a:
        np.testing.assert_array_equal(obs_a[agent], obs_b[agent])


def test_step_before_reset_says_to_call_reset():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2)
    with pytest.raises(ValueError, match=r"before reset\(\): call reset\(\) first"):
        env.step({})
    raw = coop_loc_env.raw_env("outdoor_terrain", n_robots=2)
    with pytest.raises(ValueError, match=r"call reset\(\) first"):
        raw.step(np.zeros(2))


@pytest.mark.parametrize("bad", [np.array([np.nan, 0.0]), np.array(["0.5", "-0.2"]), True])
def test_aec_env_checks_each_action_when_given_and_stays_usable(bad):
    env = coop_loc_env.env("outdoor_terrain", n_robots=3, max_cycles=5)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="robot_0"):
        env.step(bad)
    assert env.agent_selection == "robot_0"  # the same agent is still to act
    for _ in range(6):  # two full cycles of good actions run
        env.step(np.zeros(2, dtype=np.float32))
    assert env.agent_selection == "robot_0"
    ref = coop_loc_env.env("outdoor_terrain", n_robots=3, max_cycles=5)
    ref.reset(seed=0)
    for _ in range(6):
        ref.step(np.zeros(2, dtype=np.float32))
    np.testing.assert_array_equal(env.observe("robot_1"), ref.observe("robot_1"))


def test_every_scenario_is_described():
    for name in coop_loc_env.list_scenarios():
        text = coop_loc_env.describe_scenario(name)
        assert text and text != name and "\n" not in text
    assert "symmetric ring of corridors" in coop_loc_env.describe_scenario("symmetric_hallway")
    with pytest.raises(ValueError, match="unknown scenario 'nowhere'"):
        coop_loc_env.describe_scenario("nowhere")


# ---------------------------------------------------------------- docs
DOCS = Path(__file__).resolve().parents[2] / "docs"


def test_docs_list_every_scenario_and_reward_term():
    scenarios = (DOCS / "scenarios.md").read_text()
    table = scenarios[:scenarios.index("\n## ")]
    for name in coop_loc_env.list_scenarios():
        assert f"| `{name}` | `{coop_loc_env.env_id(name)}` |" in table
        assert f"## `{name}`\n\n![{name}](_static/scenarios/{name}.png)" in scenarios
        assert (DOCS / "_static" / "scenarios" / f"{name}.png").is_file()
    env = _env(reward_terms_dict=True)
    _, rewards, _, _, infos = env.step({a: np.zeros(2) for a in env.agents})
    page = (DOCS / "observations.md").read_text()
    reward_section = page[page.index("## Reward"):]
    for key in infos["robot_0"]["reward_terms"]:
        assert f"`{key}`" in reward_section
    assert rewards["robot_0"] == sum(infos["robot_0"]["reward_terms"].values())
