"""The SB3 VecEnv over one batched env samples exactly what the env copies sample."""

from __future__ import annotations

import numpy as np
import pytest

from policies.learning.sb3_batched import BatchedVecEnv
from policies.learning.sb3_vec_env import ParallelEnvVecEnv
from policies.learning.vec_env import make_env_fn

SLOT_KEYS = ("TimeLimit.truncated", "padding")


def _run(venv, actions, seed):
    venv.seed(seed)
    out = [("obs", venv.reset())]
    for a in actions:
        obs, rew, done, infos = venv.step(a)
        out += [("obs", obs), ("rew", rew), ("done", done)]
        for j, info in enumerate(infos):
            if "terminal_observation" in info:
                out.append((f"terminal {j}", info["terminal_observation"]))
            for key in SLOT_KEYS:
                if key in info:
                    out.append((f"{key} {j}", np.array(info[key])))
            if "episode" in info:
                out.append((f"episode {j}", np.array([info["episode"]["r"],
                                                      info["episode"]["l"]])))
    venv.close()
    return out


@pytest.mark.parametrize("tip", [False, True], ids=["truncation", "tip-over"])
def test_batched_vec_env_equals_the_env_copies(tip, steep_and_flat):
    kw = dict(n_robots=2, max_cycles=4)
    if tip:  # robot 0 of every world tips over at its first step: padding, then reset
        kw["start_poses"] = steep_and_flat
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (9, 6, 2)).astype(np.float32)
    copies = _run(ParallelEnvVecEnv(make_env_fn("outdoor_terrain", **kw), n_envs=3),
                  actions, seed=5)
    batched = _run(BatchedVecEnv("outdoor_terrain", n_envs=3, **kw), actions, seed=5)
    assert [k for k, _ in copies] == [k for k, _ in batched]
    for (key, a), (_, b) in zip(copies, batched, strict=True):
        np.testing.assert_array_equal(a, b, err_msg=key)
    assert any(k.startswith("padding") for k, _ in copies) == tip


def test_dict_observations_flatten_per_entry():
    venv = BatchedVecEnv("active_hallway", n_envs=2, n_particles=60, obs_format="dict",
                         max_cycles=3)
    venv.seed(0)
    obs = venv.reset()
    n = venv.num_envs
    assert {k: v.shape[0] for k, v in obs.items()} == dict.fromkeys(obs, n)
    _, _, done, infos = venv.step(np.zeros((n, 2), np.float32))
    assert not done.any()
    for _ in range(2):
        _, _, done, infos = venv.step(np.zeros((n, 2), np.float32))
    assert done.all() and set(infos[0]["terminal_observation"]) == set(obs)
    venv.close()


def test_training_on_the_batched_env_learns_the_model_the_copies_learn(tmp_path):
    from policies.learning.loader import make_policy
    from policies.learning.training import TrainConfig, train, vec_env_kind

    params, kinds = [], []
    for kind in ("batched", "copies"):
        cfg = TrainConfig(out=str(tmp_path / kind), timesteps=64, n_envs=2, n_steps=16,
                          batch_size=32, n_epochs=1, eval_freq=0, checkpoint_freq=0,
                          overrides={"n_robots": 2, "max_cycles": 10}, progress_bar=False,
                          seed=3, vec_env=kind)
        kinds.append(train(cfg)["vec_env"])
        model = make_policy(str(tmp_path / kind / "final_model.zip")).model
        params.append(np.concatenate([p.detach().numpy().ravel()
                                      for p in model.policy.parameters()]))
    assert kinds == ["batched", "copies"]
    np.testing.assert_array_equal(params[0], params[1])
    auto = TrainConfig(out="x")
    assert vec_env_kind(auto) == "batched"
    assert vec_env_kind(TrainConfig(out="x", n_envs=2, n_procs=2)) == "copies"
    assert vec_env_kind(TrainConfig(out="x", reward_mode="localize")) == "copies"
    with pytest.raises(ValueError, match="needs n_procs 1"):
        TrainConfig(out="x", n_envs=2, n_procs=2, vec_env="batched").validate()
    with pytest.raises(ValueError, match="vec_env must be one of"):
        TrainConfig(out="x", vec_env="fast").validate()
