"""The RLlib backend: time-limit cuts stay truncations, seeded sampling, train and evaluate."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ray.rllib.connectors.learner import AddOneTsToEpisodesAndTruncate
from ray.rllib.env.multi_agent_env_runner import MultiAgentEnvRunner
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.rllib.utils.postprocessing.value_predictions import compute_value_targets
from ray.tune.registry import register_env

import coop_loc_env
from policies.learning.loader import load_learned_policy
from policies.learning.rllib_backend import CoopLocMultiAgentEnv, RLlibPolicy, ppo_config

GAMMA, VALUE = 0.9, 5.0


def _rllib_pettingzoo_env(config):
    return ParallelPettingZooEnv(coop_loc_env.parallel_env(**config))


register_env("coop_loc_rllib_pettingzoo", _rllib_pettingzoo_env)


def _last_value_targets(episodes) -> dict[str, tuple[float, float]]:
    """Per agent: (last reward, GAE value target of its last step) with V = VALUE
    everywhere, through RLlib's own bootstrap step and value-target function."""
    batch: dict = {}
    AddOneTsToEpisodesAndTruncate()(rl_module=None, batch=batch, episodes=episodes,
                                    shared_data={})
    out = {}
    for key, term in batch["terminateds"].items():
        agent, trunc = key[1], batch["truncateds"][key]
        sa = episodes[0].agent_episodes[agent]
        rewards = np.asarray(sa.get_rewards(), dtype=float)  # with the appended 0.0
        targets = compute_value_targets(
            values=np.full(len(rewards), VALUE), rewards=rewards,
            terminateds=np.asarray(term), truncateds=np.asarray(trunc),
            gamma=GAMMA, lambda_=0.95,
        )
        out[agent] = (float(rewards[-2]), float(targets[-2]))
    return out


@pytest.mark.parametrize("wrapper", ["ours", "rllib_pettingzoo"])
def test_time_limit_cut_is_bootstrapped_and_tip_over_is_not(steep_and_flat, wrapper):
    env_config = {"n_robots": 2, "max_cycles": 3, "start_poses": steep_and_flat}
    config = ppo_config(env_config, seed=1).training(gamma=GAMMA)
    if wrapper == "rllib_pettingzoo":
        config = config.environment("coop_loc_rllib_pettingzoo")
    runner = MultiAgentEnvRunner(config=config)
    episodes = runner.sample(num_episodes=1, random_actions=True)
    tipped, driving = (episodes[0].agent_episodes[a] for a in ("robot_0", "robot_1"))
    assert (len(tipped), len(driving)) == (1, 3)
    targets = _last_value_targets(episodes)
    r_tip, v_tip = targets["robot_0"]
    assert r_tip <= -10 and v_tip == pytest.approx(r_tip)  # terminated: no bootstrap
    r_cut, v_cut = targets["robot_1"]
    assert tipped.is_terminated and not tipped.is_truncated
    if wrapper == "ours":
        assert driving.is_truncated and not driving.is_terminated
        assert v_cut == pytest.approx(r_cut + GAMMA * VALUE)  # bootstrapped
    else:  # RLlib's own wrapper: the max_cycles cut becomes a termination
        assert driving.is_terminated
        assert v_cut == pytest.approx(r_cut)
    runner.stop()


def test_wrapper_step_flags_and_render_argument():
    env = CoopLocMultiAgentEnv({"n_robots": 2, "max_cycles": 2, "render_mode": "rgb_array"})
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"robot_0", "robot_1"} and env.agents == ["robot_0", "robot_1"]
    act = {a: np.zeros(2, np.float32) for a in env.agents}
    _, _, term, trunc, _ = env.step(act)
    assert term == {"robot_0": False, "robot_1": False, "__all__": False}
    assert trunc == {"robot_0": False, "robot_1": False, "__all__": False}
    _, _, term, trunc, _ = env.step(act)
    assert trunc == {"__all__": True} and not any(term.values()) and env.agents == []
    assert env.render().ndim == 3
    assert _rllib_pettingzoo_env({"render_mode": "rgb_array"}).render().ndim == 3


def _first_batch(seed: int) -> list[np.ndarray]:
    runner = MultiAgentEnvRunner(config=ppo_config({"n_robots": 2, "max_cycles": 20}, seed=seed))
    episodes = runner.sample(num_timesteps=30)
    runner.stop()
    out = []
    for ep in episodes:
        for agent in sorted(ep.agent_episodes):
            sa = ep.agent_episodes[agent]
            out += [np.asarray(sa.get_observations()), np.asarray(sa.get_actions()),
                    np.asarray(sa.get_rewards())]
    return out


def test_same_seed_same_first_batch():
    a, b, c = _first_batch(4), _first_batch(4), _first_batch(5)
    assert len(a) == len(b) and sum(len(x) for x in a[1::3]) >= 30
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(a[1], c[1])  # another seed, other actions


def test_tiny_training_then_evaluate_and_compare(tmp_path, script_main, mean_position_error):
    out = tmp_path / "run"
    train, evaluate = script_main("train"), script_main("evaluate")
    rc = train(["--backend", "rllib", "--num-env-runners", "1", "--timesteps", "1000",
                "--n-steps", "128", "--n-envs", "2", "--batch-size", "128", "--n-epochs", "2",
                "--max-cycles", "40", "--set", "n_robots=2", "--checkpoint-freq", "500",
                "--seed", "3", "--out", str(out)])
    assert rc == 0
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["timesteps"] == 1024 and summary["iterations"] == 2  # 2 x 256 x 2 robots
    assert (out / "checkpoint" / "rllib_checkpoint.json").is_file()
    assert len(list((out / "checkpoints").iterdir())) == 2
    assert any((out / "tb").iterdir())
    policy = load_learned_policy(out)
    assert isinstance(policy, RLlibPolicy)
    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    policy.reset(env)
    act = policy.act(obs)
    assert set(act) == {"robot_0", "robot_1"} and all(np.abs(a).max() <= 1 for a in act.values())
    np.testing.assert_array_equal(act["robot_0"], policy.act(obs)["robot_0"])  # deterministic
    report = tmp_path / "eval.json"
    assert evaluate(["--policy", str(out), "--episodes", "1", "--max-cycles", "10",
                     "--set", "n_robots=2", "--json", str(report), "--no-progress"]) == 0
    data = json.loads(report.read_text())
    assert data["policy"] == str(out)
    expected = mean_position_error("outdoor_terrain", load_learned_policy(out), [0], n_robots=2,
                                   max_cycles=10)
    assert data["summary"]["localization_error_m"]["mean"] == pytest.approx(expected, rel=1e-12)
    assert evaluate(["--compare", f"random,{out}", "--episodes", "1", "--max-cycles", "10",
                     "--set", "n_robots=2", "--plot-dir", str(tmp_path), "--no-progress"]) == 0
    with pytest.raises(ValueError, match="observations of shape"):
        policy.reset(coop_loc_env.parallel_env(n_robots=2, map_patch_obs=5))


def test_bad_rllib_options_exit_2(tmp_path, script_main, capsys):
    train = script_main("train")
    assert train(["--backend", "rllib", "--algo", "SAC", "--out", str(tmp_path)]) == 2
    assert "algo='SAC'" in capsys.readouterr().err
    assert train(["--num-env-runners", "2", "--out", str(tmp_path)]) == 2
    assert "--backend rllib" in capsys.readouterr().err
    assert train(["--backend", "rllib", "--num-env-runners", "-1", "--out", str(tmp_path)]) == 2
    assert "num_env_runners" in capsys.readouterr().err


def test_dict_observation_is_sampled_through_the_flattening_connector():
    """RLlib's default encoders take vectors: ``obs_format="dict"`` gets a flattening
    connector, and the env runner samples the ``Dict`` observations through the module."""
    config = {"scenario": "active_hallway", "n_robots": 2, "max_cycles": 6, "n_particles": 100,
              "obs_format": "dict", "belief_map_cells": 8}
    runner = MultiAgentEnvRunner(config=ppo_config(config, seed=0))
    episodes = runner.sample(num_timesteps=8)
    runner.stop()
    space = CoopLocMultiAgentEnv(config).observation_spaces["robot_0"]
    assert set(space) == {"vector", "belief_map"}
    sa = episodes[0].agent_episodes["robot_0"]
    first = np.asarray(sa.get_observations()[0])  # flattened by the connector: both blocks
    assert first.shape == (space["vector"].shape[0] + 10 * 8 * 8,)
    actions = np.asarray(sa.get_actions())
    assert len(actions) >= 4 and np.all(np.isfinite(actions))
