"""Infos that trainers can tensorize: flat reward terms, one key set per team, done agents."""

from __future__ import annotations

import math

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env import RobotSpec

TERMS = ("localization", "coverage", "collision", "tip_over")
MIXED = (RobotSpec(estimator="ekf"), RobotSpec(estimator="mcl"))


def _step(env, value=0.3):
    return env.step({a: np.full(2, value, np.float32) for a in env.agents})


def test_reward_terms_flat_keys_match_the_dict_and_sum_to_the_reward():
    env = coop_loc_env.parallel_env(max_cycles=5, reward_coverage_weight=0.5,
                                    reward_terms_dict=True)
    _, infos = env.reset(seed=3)
    assert all(infos[a]["reward_localization"] == infos[a]["reward_terms"]["localization"]
               for a in env.agents)
    _, rewards, _, _, infos = _step(env)
    for agent, info in infos.items():
        flat = {k: v for k, v in info.items() if k.startswith("reward_") and k != "reward_terms"}
        assert flat == {f"reward_{name}": v for name, v in info["reward_terms"].items()}
        assert set(TERMS) <= set(info["reward_terms"])
        assert rewards[agent] == pytest.approx(sum(flat.values()))


def test_a_reward_term_added_in_reward_terms_reaches_the_reward_and_the_infos():
    from coop_loc_env.env import CoopLocParallelEnv

    class WithBonus(CoopLocParallelEnv):
        def _reward_terms(self, *args):
            terms = super()._reward_terms(*args)
            return {**terms, "bonus": [0.25] * self.config.n_robots}

    plain = CoopLocParallelEnv(max_cycles=3)
    bonus = WithBonus(max_cycles=3, reward_terms_dict=True)
    plain.reset(seed=1)
    bonus.reset(seed=1)
    _, base_rewards, _, _, _ = _step(plain)
    _, rewards, _, _, infos = _step(bonus)
    for agent, info in infos.items():
        assert info["reward_bonus"] == info["reward_terms"]["bonus"] == 0.25
        assert rewards[agent] == pytest.approx(base_rewards[agent] + 0.25)


def test_default_infos_hold_only_numbers_and_arrays():
    env = coop_loc_env.parallel_env(max_cycles=5)
    _, infos = env.reset(seed=0)
    _, _, _, _, step_infos = _step(env)
    for info in [*infos.values(), *step_infos.values()]:
        assert "reward_terms" not in info
        for key, value in info.items():
            assert np.asarray(value).dtype.kind in "biuf", key
    with pytest.raises(ValueError, match="reward_terms_dict"):
        coop_loc_env.parallel_env(reward_terms_dict="no")


def test_mixed_team_agents_share_info_keys_with_nan_where_not_reported():
    env = coop_loc_env.parallel_env(n_robots=2, team=MIXED, max_cycles=5, n_particles=100)
    _, infos = env.reset(seed=1)
    _, _, _, _, step_infos = _step(env)
    for batch in (infos, step_infos):
        assert list(batch["robot_0"]) != [] and set(batch["robot_0"]) == set(batch["robot_1"])
        for key in ("particle_spread", "n_particles", "detections_used"):
            assert math.isnan(batch["robot_0"][key])  # the EKF robot
            assert np.isfinite(batch["robot_1"][key])  # the MCL robot
    assert step_infos["robot_1"]["n_particles"] >= 10


def test_homogeneous_ekf_team_has_no_estimator_extras():
    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=5)
    _, infos = env.reset(seed=1)
    assert all("particle_spread" not in i for i in infos.values())


def test_actions_of_done_agents_are_ignored(steep_and_flat):
    steep, flat = steep_and_flat
    kw = dict(n_robots=2, max_cycles=4, start_poses=(steep, flat))
    env = coop_loc_env.parallel_env(**kw)
    ref = coop_loc_env.parallel_env(**kw)
    env.reset(seed=0)
    ref.reset(seed=0)
    _, _, term, _, _ = _step(env, 0.1)
    _step(ref, 0.1)
    assert term == {"robot_0": True, "robot_1": False} and env.agents == ["robot_1"]
    # robot_0 is done: its action (even a malformed one) is ignored, robot_1 must act
    obs, rew, _, _, _ = env.step({"robot_0": np.array([np.nan, 7.0]), "robot_1": np.ones(2)})
    ref_obs, ref_rew, _, _, _ = ref.step({"robot_1": np.ones(2)})
    np.testing.assert_array_equal(obs["robot_1"], ref_obs["robot_1"])
    assert rew == ref_rew
    with pytest.raises(ValueError, match="missing actions"):
        env.step({"robot_0": np.zeros(2)})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"robot_1": np.zeros(2), "robot_9": np.zeros(2)})


def test_render_accepts_the_env_render_mode_as_argument():
    env = coop_loc_env.parallel_env(max_cycles=5, render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render("rgb_array").ndim == 3
    assert env.render(None).ndim == 3
    with pytest.raises(ValueError, match="human"):
        env.render("human")
    env.close()


def test_info_keys_keeps_only_the_named_entries_in_that_order():
    keys = ["coverage", "position_error", "particle_spread"]
    env = coop_loc_env.parallel_env(n_robots=2, team=MIXED, max_cycles=5, n_particles=100,
                                    info_keys=keys)
    full = coop_loc_env.parallel_env(n_robots=2, team=MIXED, max_cycles=5, n_particles=100)
    _, infos = env.reset(seed=2)
    full.reset(seed=2)
    _, rewards, _, _, step_infos = _step(env)
    _, full_rewards, _, _, full_infos = _step(full)
    assert rewards == full_rewards  # the rewards do not depend on what the infos keep
    for agent, info in step_infos.items():
        assert list(info) == keys and list(infos[agent]) == keys
        np.testing.assert_equal(info, {k: full_infos[agent][k] for k in keys})
    with pytest.raises(ValueError, match="'nope'"):
        coop_loc_env.parallel_env(max_cycles=5, info_keys=["nope"]).reset(seed=0)
    with pytest.raises(ValueError, match="info_keys"):
        coop_loc_env.parallel_env(info_keys="coverage")


def test_team_entries_may_be_dicts_of_robot_spec_fields():
    from policies.experiments.runner import parse_overrides

    overrides = parse_overrides(["team=[{'estimator': 'ekf'}, {'estimator': 'mcl', "
                                 "'has_gps': False}]"])
    env = coop_loc_env.parallel_env(n_robots=4, n_particles=100, **overrides)
    assert env.config.team == (RobotSpec(estimator="ekf"),
                               RobotSpec(estimator="mcl", has_gps=False))
    assert env.config.estimators == ("ekf", "mcl", "ekf", "mcl")
    single = coop_loc_env.parallel_env(n_robots=2, team={"has_gps": False})
    assert single.config.team == (RobotSpec(has_gps=False),)
    with pytest.raises(ValueError, match="'estimatr'"):
        coop_loc_env.parallel_env(team=[{"estimatr": "ekf"}])
    with pytest.raises(ValueError, match="team entries"):
        coop_loc_env.parallel_env(team=["ekf"])
