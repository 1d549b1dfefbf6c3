"""Training on the dict observation: the belief-map CNN, cloning with dict observations, and
a saved model that carries the observation settings it was trained with."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch
from gymnasium import spaces

import coop_loc_env
from policies.experiments.compare import compare
from policies.learning.belief_cnn import BeliefMapExtractor
from policies.learning.imitation import behaviour_clone, collect_demonstrations, make_teacher
from policies.learning.loader import make_policy
from policies.learning.training import TrainConfig, make_model, make_vec_env, train
from policies.learning.vec_env import make_env_fn

SMALL = dict(n_robots=2, max_cycles=6, n_particles=100, belief_map_cells=8)


def _space(cells: int = 8, channels: int = 10, n_vector: int = 5) -> spaces.Dict:
    return spaces.Dict({
        "vector": spaces.Box(-1, 1, (n_vector,), np.float32),
        "belief_map": spaces.Box(0, 1, (channels, cells, cells), np.float32),
    })


def test_extractor_reads_the_map_and_passes_the_vector_through():
    torch.manual_seed(0)
    ext = BeliefMapExtractor(_space(), map_features=16)
    assert ext.features_dim == 16 + 5
    vec = torch.linspace(-1, 1, 5).repeat(2, 1)
    maps = torch.zeros((2, 10, 8, 8))
    maps[1, 3, 2, 5] = 0.5  # mass in one cell of the second observation only
    out = ext({"vector": vec, "belief_map": maps})
    assert out.shape == (2, 21)
    torch.testing.assert_close(out[:, 16:], vec)  # the vector as it is
    assert not torch.allclose(out[0, :16], out[1, :16])  # the map changes the features


def test_extractor_rejects_other_spaces():
    with pytest.raises(ValueError, match="Dict observation"):
        BeliefMapExtractor(spaces.Box(-1, 1, (4,), np.float32))
    with pytest.raises(ValueError, match="H, W >= 8"):
        BeliefMapExtractor(_space(cells=4))
    with pytest.raises(ValueError, match="map_features"):
        BeliefMapExtractor(_space(), map_features=0)


def test_cloning_learns_from_dict_observations(tmp_path):
    """Demonstrations keep both blocks, and cloning fits the teacher's actions on them."""
    cfg = TrainConfig(out=str(tmp_path), scenario="active_hallway",
                      overrides={**SMALL, "max_cycles": 12}, obs_format="dict", n_steps=8,
                      batch_size=8, n_envs=1)
    demos = collect_demonstrations(make_env_fn("active_hallway", obs_format="dict",
                                               **{**SMALL, "max_cycles": 12}),
                                   make_teacher("corridor"), 2, seed=5)
    n = len(demos["actions"])
    assert set(demos["obs"]) == {"vector", "belief_map"}
    assert demos["obs"]["belief_map"].shape == (n, 10, 8, 8) and n == 2 * 12 * 2
    venv = make_vec_env(cfg)
    try:
        model = make_model(cfg, venv, None)
        before = behaviour_clone(model, demos, epochs=1, learning_rate=1e-6, seed=0)
        after = behaviour_clone(model, demos, epochs=60, seed=0)
    finally:
        venv.close()
    assert after["action_mse"] < 0.5 * before["action_mse"]
    bad = {**demos, "actions": demos["actions"][:-1]}
    with pytest.raises(ValueError, match="demos do not match"):
        behaviour_clone(model, bad, epochs=1)


def test_saved_model_carries_its_observation_settings(tmp_path):
    """A model trained on the dict observation is evaluated on it with no overrides given,
    and an env built otherwise is refused with a message naming the settings."""
    cfg = TrainConfig(out=str(tmp_path), scenario="active_hallway", overrides=dict(SMALL),
                      obs_format="dict", timesteps=32, n_steps=8, batch_size=8, n_envs=1,
                      eval_freq=0, checkpoint_freq=0, progress_bar=False, bc_from="corridor",
                      bc_episodes=1, bc_epochs=1)
    summary = train(cfg)
    policy = make_policy(summary["final_model"])
    assert policy.env_settings == {"obs_format": "dict", "belief_map_cells": 8,
                                   "belief_map_headings": 8, "belief_modes": 4}
    overrides = {k: v for k, v in SMALL.items() if k != "belief_map_cells"}
    rep = compare("active_hallway", [summary["final_model"], "corridor"], 1, 3, overrides,
                  progress=False)
    assert rep["episodes"][summary["final_model"]][0]["steps"] == 6
    path = Path(__file__).resolve().parents[2] / "scripts" / "bench" / "policy_step.py"
    spec = importlib.util.spec_from_file_location("policy_step", path)
    policy_step = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(policy_step)
    act_ms, env_ms = policy_step.bench("active_hallway", summary["final_model"], 1, overrides)
    assert act_ms > 0 and env_ms > 0  # the benchmark builds the env the model reads
    env = coop_loc_env.parallel_env("active_hallway", **overrides)  # flat observations
    env.reset(seed=0)
    with pytest.raises(ValueError, match="obs_format"):
        policy.reset(env)
    env.close()
