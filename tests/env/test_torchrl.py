"""TorchRL's PettingZooWrapper runs the env as it is (specs, rollouts, early terminations)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchrl.envs.libs.pettingzoo import PettingZooWrapper
from torchrl.envs.utils import check_env_specs

import coop_loc_env
from coop_loc_env import RobotSpec

MIXED = (RobotSpec(estimator="ekf"), RobotSpec(estimator="mcl"))


def _wrapped(**overrides) -> PettingZooWrapper:
    kw = dict(n_robots=2, max_cycles=6, n_particles=100) | overrides
    pz = coop_loc_env.parallel_env("outdoor_terrain", **kw)
    return PettingZooWrapper(env=pz, use_mask=True, done_on_any=False, seed=0)


@pytest.mark.parametrize("team", [(RobotSpec(),), MIXED], ids=["ekf", "ekf+mcl"])
def test_check_env_specs_and_rollout(team):
    env = _wrapped(team=team)
    check_env_specs(env, seed=0)
    td = env.rollout(20)  # stops when every agent is done
    assert td.batch_size == torch.Size([6])  # max_cycles, then done
    robot = td["next", "robot"]
    assert robot["observation"].shape[1] == 2
    assert robot["truncated"][-1].all() and not robot["terminated"].any()
    info = robot["info"]
    reward = sum(info[k] for k in info.keys() if k.startswith("reward_"))
    torch.testing.assert_close(reward, robot["reward"][..., 0])
    if team == MIXED:
        assert torch.isnan(info["particle_spread"][:, 0]).all()
        assert torch.isfinite(info["particle_spread"][:, 1]).all()
    env.close()


def test_tip_over_terminates_one_agent_the_other_drives_on(steep_and_flat):
    env = _wrapped(start_poses=steep_and_flat, max_cycles=4)
    td = env.rollout(10)  # actions are sent for the done agent too
    robot = td["next", "robot"]
    assert td.batch_size == torch.Size([4])
    assert robot["terminated"][:, 0, 0].tolist() == [True, True, True, True]
    assert robot["terminated"][:, 1, 0].tolist() == [False] * 4
    assert robot["truncated"][:, 1, 0].tolist() == [False, False, False, True]
    assert robot["mask"][:, 0].tolist() == [False] * 4  # done from the first step on
    assert robot["mask"][:, 1].tolist() == [True, True, True, False]
    assert robot["reward"][0, 0, 0] <= -10.0  # the tip-over penalty
    moved = np.diff(robot["info", "true_pose"][:, 1, :2].numpy(), axis=0)
    assert np.abs(moved).sum() > 0  # robot_1 kept driving
    env.close()
