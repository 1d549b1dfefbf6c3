"""torchrl_env(num_envs=B): specs, rollouts equal to the vector env, partial resets."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

import coop_loc_env
from coop_loc_env.vector import CoopLocVectorEnv


def test_specs_and_rollout_replay_the_vector_env():
    env = coop_loc_env.torchrl_env("rendezvous", num_envs=3, seed=4, max_cycles=5)
    assert env.batch_size == torch.Size([3])
    check_env_specs(env, seed=4)
    env.set_seed(4)
    td = env.rollout(7, break_when_any_done=False)  # the worlds end at step 5, then reset
    assert td.batch_size == torch.Size([3, 7])
    robot = td["next", "robot"]
    assert robot["observation"].shape == (3, 7, 4, env._obs_dim)
    assert td["next", "done"][:, :, 0].tolist() == [[False] * 4 + [True, False, False]] * 3
    assert td["next", "truncated"][:, 4].all() and not td["next", "terminated"].any()
    ref = coop_loc_env.vector_env("rendezvous", num_envs=3, max_cycles=5,
                                  info_keys=("position_error",))
    ref.reset(seed=4)
    for t in range(5):
        obs, rew, _, _, infos = ref.step(td["robot", "action"][:, t].numpy())
        if t == 4:  # the vector env reset the worlds in that step; TorchRL's next one
            restart, obs = obs, infos["final_obs"]
        np.testing.assert_array_equal(robot["observation"][:, t].numpy(), obs)
        np.testing.assert_array_equal(robot["reward"][:, t, :, 0].numpy(),
                                      rew.astype(np.float32))
        np.testing.assert_array_equal(robot["info", "position_error"][:, t].numpy(),
                                      infos["position_error"].astype(np.float32))
    # TorchRL reset the worlds as the vector env did: each continuing its own stream
    np.testing.assert_array_equal(td["robot", "observation"][:, 5].numpy(), restart)


def test_reset_mask_resets_only_the_named_worlds():
    env = coop_loc_env.torchrl_env("rendezvous", num_envs=3, seed=0)
    env.reset()
    act = TensorDict({"robot": TensorDict({"action": torch.zeros(3, 4, 2)},
                                          batch_size=(3, 4))}, batch_size=(3,))
    env.step(act)
    env.reset(TensorDict({"_reset": torch.tensor([[False], [True], [False]])},
                         batch_size=(3,)))
    assert [w.step_count for w in env.env.envs] == [1, 0, 1]


def test_needs_box_observations_and_no_autoreset():
    with pytest.raises(ValueError, match="Box observations"):
        coop_loc_env.torchrl_env("active_hallway", num_envs=2, obs_format="dict",
                                 n_particles=50)
    from coop_loc_env.torchrl_vector import CoopLocTorchRLVectorEnv

    with pytest.raises(ValueError, match="autoreset=False"):
        CoopLocTorchRLVectorEnv(CoopLocVectorEnv("rendezvous", num_envs=2))
