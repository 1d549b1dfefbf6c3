"""A tiny training run end to end: train.py, checkpoints, resume, evaluate.py loads the model."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

import coop_loc_env
from policies.episode import run_episode
from policies.learning.learned import LearnedPolicy
from policies.learning.loader import load_learned_policy, make_policy
from policies.learning.training import EVAL_SEED, TrainConfig, find_checkpoint, train

ROOT = Path(__file__).resolve().parents[2]
TINY = ["--scenario", "outdoor_terrain", "--estimator", "ekf", "--set", "n_robots=2",
        "--max-cycles", "20", "--n-envs", "2", "--n-steps", "32", "--batch-size", "64",
        "--n-epochs", "2", "--no-progress"]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.main


def test_tiny_training_saves_a_model_that_evaluate_loads(tmp_path, capsys,
                                                          mean_position_error):
    out = tmp_path / "run"
    rc = _script("train")(TINY + ["--timesteps", "256", "--seed", "3", "--out", str(out),
                                  "--eval-freq", "128", "--eval-episodes", "1",
                                  "--checkpoint-freq", "128", "--reward-coverage-weight", "0.5"])
    assert rc == 0
    final = out / "final_model.zip"
    assert final.is_file()
    summary = json.loads((out / "train_summary.json").read_text())
    assert summary["timesteps"] == 256  # 2 copies x 2 robots x 32 steps x 2 rollouts
    assert [e["timesteps"] for e in summary["evals"]] == [128, 256]
    config = json.loads((out / "train_config.json").read_text())
    # the FSM on the evaluation's seeds, in the run's env
    expected = mean_position_error("outdoor_terrain", make_policy("fsm"), [EVAL_SEED],
                                   **config["overrides"], estimator=config["estimator"])
    assert summary["baseline"]["localization_error_m"] == pytest.approx(expected, rel=1e-12)
    assert config["overrides"]["reward_coverage_weight"] == 0.5
    assert config["estimator"] == "ekf"
    assert sorted(p.name for p in (out / "checkpoints").glob("*.zip")) == [
        "model_128_steps.zip", "model_256_steps.zip"]
    assert list((out / "tb").glob("PPO_*/events.out.tfevents.*"))
    capsys.readouterr()
    rc = _script("evaluate")(["--policy", str(final), "--episodes", "1", "--max-cycles", "10",
                              "--set", "n_robots=2", "--no-progress"])
    assert rc == 0
    assert "team localization error (m)" in capsys.readouterr().out
    # the loaded model acts like the in-memory one would: deterministic, inside the box
    policy = load_learned_policy(out)
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    policy.reset(env)
    a1, a2 = policy.act(obs), policy.act(obs)
    assert set(a1) == {"robot_0", "robot_1"}
    for agent in a1:
        np.testing.assert_array_equal(a1[agent], a2[agent])
        assert np.all(np.abs(a1[agent]) <= 1)


def test_resume_continues_the_step_counter(tmp_path):
    base = dict(scenario="outdoor_terrain", estimator="ekf",
                overrides={"n_robots": 2, "max_cycles": 20}, n_envs=1, n_steps=32,
                batch_size=64, n_epochs=1, eval_freq=0, progress_bar=True)
    first = train(TrainConfig(out=str(tmp_path / "a"), timesteps=64, checkpoint_freq=64, **base))
    assert first["timesteps"] == 64
    ckpt = find_checkpoint(tmp_path / "a")
    assert ckpt.name == "model_64_steps.zip"
    second = train(TrainConfig(out=str(tmp_path / "b"), timesteps=64, checkpoint_freq=0,
                               resume=str(tmp_path / "a"), **base))
    assert second["timesteps"] == 128
    with pytest.raises(ValueError, match="no checkpoint"):
        find_checkpoint(tmp_path / "nothing")


def test_same_seed_same_model(tmp_path):
    params = []
    for name in ("a", "b"):
        cfg = TrainConfig(out=str(tmp_path / name), timesteps=64, n_envs=1, n_steps=32,
                          batch_size=32, n_epochs=1, overrides={"n_robots": 2, "max_cycles": 20},
                          eval_freq=0, checkpoint_freq=0, progress_bar=False, seed=7)
        train(cfg)
        model = make_policy(str(tmp_path / name / "final_model.zip")).model
        params.append(np.concatenate([p.detach().numpy().ravel()
                                      for p in model.policy.parameters()]))
    np.testing.assert_array_equal(params[0], params[1])


def test_learned_policy_checks_observation_shape(tmp_path):
    cfg = TrainConfig(out=str(tmp_path / "m"), timesteps=32, n_envs=1, n_steps=16,
                      batch_size=32, n_epochs=1, overrides={"n_robots": 2, "max_cycles": 10},
                      eval_freq=0, checkpoint_freq=0, progress_bar=False)
    train(cfg)
    import torch

    torch.set_num_threads(2)
    model = make_policy(str(tmp_path / "m" / "final_model.zip")).model
    assert torch.get_num_threads() == 1  # acting on one team observation: one thread
    torch.set_num_threads(2)
    LearnedPolicy(model, threads=None)
    assert torch.get_num_threads() == 2
    policy = LearnedPolicy(model)
    assert torch.get_num_threads() == 1
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, max_detections_obs=1)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="expects observations of shape"):
        policy.reset(env)
    ok = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, max_cycles=6)
    ep = run_episode(ok, policy, seed=1)
    assert ep["steps"] == 6
    with pytest.raises(ValueError, match="stable-baselines3 model"):
        LearnedPolicy(object())


def test_train_rejects_bad_input(tmp_path, capsys):
    main = _script("train")
    assert main(["--out", str(tmp_path), "--n-envs", "0", "--no-progress"]) == 2
    assert "n_envs" in capsys.readouterr().err
    assert main(["--out", str(tmp_path), "--set", "n_robotz=2", "--no-progress"]) == 2
    assert "n_robotz" in capsys.readouterr().err
    assert main(["--out", str(tmp_path), "--n-envs", "1", "--n-procs", "2"]) == 2
    assert "n_procs" in capsys.readouterr().err
    with pytest.raises(ValueError, match="max_wall_s"):
        TrainConfig(out="x", max_wall_s=-1).validate()


def test_train_says_when_timesteps_round_up_to_whole_rollouts(tmp_path, capsys):
    from policies.learning.training import trained_timesteps

    cfg = TrainConfig(out=str(tmp_path / "x"), scenario="outdoor_terrain", timesteps=200,
                      n_envs=2, n_steps=32, overrides={"n_robots": 2})
    assert trained_timesteps(cfg) == 256  # rollouts of 2 copies x 2 robots x 32 steps
    assert trained_timesteps(dataclasses.replace(cfg, timesteps=256)) == 256
    out = tmp_path / "run"
    assert _script("train")(TINY + ["--timesteps", "200", "--out", str(out), "--eval-freq", "0",
                                    "--checkpoint-freq", "0"]) == 0
    assert "note: training 256 agent steps, not 200" in capsys.readouterr().out
    assert json.loads((out / "train_summary.json").read_text())["timesteps"] == 256
