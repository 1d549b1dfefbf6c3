"""Behaviour cloning (policies.learning.imitation), the time-to-localize reward and
train.py --bc-from."""

from __future__ import annotations

import json

import numpy as np
import pytest

import coop_loc_env
from policies.experiments.compare import paired_difference, resolve_policy
from policies.learning.imitation import (
    behaviour_clone,
    collect_demonstrations,
    discounted_returns,
    make_teacher,
)
from policies.learning.training import TrainConfig, make_model, make_vec_env
from policies.learning.vec_env import TimeToLocalizeReward, make_env_fn

HALL = dict(n_robots=2, n_particles=100, max_cycles=6)


def test_discounted_returns_with_and_without_the_truncation_tail():
    r = np.array([-1.0, -1.0, 0.0])
    np.testing.assert_allclose(discounted_returns(r, 0.5, truncated=False), [-1.5, -1.0, 0.0])
    r = np.array([-1.0, -1.0])
    # tail: the last reward forever, -1 / (1 - 0.5) = -2, discounted once more per step
    np.testing.assert_allclose(discounted_returns(r, 0.5, truncated=True), [-2.0, -2.0])


def test_localize_reward_counts_steps_until_the_spread_first_drops():
    fn = make_env_fn("symmetric_hallway", reward_mode="localize",
                     reward_kwargs={"step_reward": 0.5, "threshold": 1e-6}, **HALL)
    env = fn()
    assert isinstance(env, TimeToLocalizeReward)
    obs, _ = env.reset(seed=0)
    assert env.possible_agents == ["robot_0", "robot_1"]
    _, rew, _, _, infos = env.step({a: np.zeros(2, np.float32) for a in env.agents})
    assert rew == {"robot_0": -0.5, "robot_1": -0.5}  # nobody gets below 1 micrometre
    assert all("particle_spread" in i for i in infos.values())
    # a threshold every belief meets: localized at once, reward 0
    env2 = TimeToLocalizeReward(coop_loc_env.parallel_env("symmetric_hallway", **HALL),
                                threshold=1e6, team_weight=0.5)
    env2.reset(seed=0)
    _, rew, _, _, _ = env2.step({a: np.zeros(2, np.float32) for a in env2.agents})
    assert rew == {"robot_0": 0.0, "robot_1": 0.0}
    # once localized, a robot stays so for the episode; the team term pays for the others
    env2.threshold = 1e-6
    env2.localized[1] = False
    _, rew, _, _, _ = env2.step({a: np.zeros(2, np.float32) for a in env2.agents})
    assert rew["robot_0"] == pytest.approx(-0.1 * 0.5 * 0.5)
    assert rew["robot_1"] == pytest.approx(-0.1 * (0.5 + 0.5 * 0.5))
    env2.reset(seed=1)
    assert not env2.localized.any()
    with pytest.raises(ValueError, match="team_weight"):
        make_env_fn("symmetric_hallway", reward_mode="localize", reward_kwargs={"team_weight": 2})
    with pytest.raises(ValueError, match="reward_mode"):
        make_env_fn("symmetric_hallway", reward_mode="nope")


def test_cloning_fits_the_teacher_and_the_returns():
    cfg = TrainConfig(out="unused", scenario="symmetric_hallway", overrides=dict(HALL),
                      reward_mode="localize", normalize_reward=False, n_envs=1, n_steps=8,
                      batch_size=16, progress_bar=False)
    demos = collect_demonstrations(cfg.env_fn(), make_teacher("wander:0.8"), 2, seed=5)
    assert demos["obs"].shape == (2 * 2 * 6, coop_loc_env.parallel_env(
        "symmetric_hallway", **HALL).observation_space("robot_0").shape[0])
    assert demos["actions"].shape == (24, 2) and np.all(np.abs(demos["actions"]) <= 1)
    assert np.all(demos["returns"] <= 0)
    venv = make_vec_env(cfg)
    try:
        model = make_model(cfg, venv, None)
        fit = behaviour_clone(model, demos, epochs=150, batch_size=8, log_std=-1.5)
    finally:
        venv.close()
    var_a = float(demos["actions"].var(axis=0).sum() / 2)
    assert fit["action_mse"] < 0.5 * var_a + 1e-3  # far better than the mean action
    assert fit["value_mse"] < 0.5 * float(demos["returns"].var()) + 1e-3
    np.testing.assert_allclose(model.policy.log_std.detach().numpy(), [-1.5, -1.5])
    with pytest.raises(ValueError, match="epochs"):
        behaviour_clone(model, demos, epochs=0)


def test_make_teacher_and_wander_specs():
    assert make_teacher("wander").speed == 0.6
    assert make_teacher("wander:1").speed == 1.0
    assert resolve_policy("wander:0.9").speed == 0.9
    with pytest.raises(ValueError):
        make_teacher("wander:fast")
    with pytest.raises(ValueError):
        resolve_policy("wander:2")
    with pytest.raises(ValueError):
        make_teacher("fsm:1")


def test_train_cli_clones_then_fine_tunes(tmp_path, script_main, capsys):
    out = tmp_path / "bc"
    rc = script_main("train")([
        "--scenario", "symmetric_hallway", "--set", "n_robots=2", "--set", "n_particles=100",
        "--max-cycles", "6", "--reward", "localize", "--no-reward-norm", "--bc-from", "wander",
        "--bc-episodes", "1", "--bc-epochs", "2", "--n-envs", "1", "--n-steps", "8",
        "--batch-size", "16", "--n-epochs", "1", "--timesteps", "16", "--eval-freq", "0",
        "--checkpoint-freq", "0", "--no-progress", "--out", str(out)])
    assert rc == 0
    assert (out / "bc_model.zip").is_file() and (out / "final_model.zip").is_file()
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["bc"]["teacher"] == "wander" and summary["bc"]["samples"] == 12
    assert summary["total_wall_s"] >= summary["wall_s"]
    assert "behaviour cloning of wander" in capsys.readouterr().out
    assert script_main("train")(["--out", str(tmp_path / "x"), "--bc-from", "nope",
                                 "--no-progress"]) == 2
    assert script_main("train")(["--out", str(tmp_path / "x"), "--bc-from", "wander",
                                 "--algo", "SAC", "--no-progress"]) == 2


def test_paired_difference():
    rep = {"episodes": {"a": [{"t": 3.0}, {"t": 5.0}, {"t": 4.0}],
                        "b": [{"t": 1.0}, {"t": 4.0}, {"t": 1.0}]}}
    d = paired_difference(rep, "a", "b", "t")
    assert d["mean"] == pytest.approx(2.0) and d["n"] == 3
    assert d["low"] < 2.0 < d["high"]
    rep["episodes"]["b"].pop()
    with pytest.raises(ValueError, match="different numbers"):
        paired_difference(rep, "a", "b", "t")
