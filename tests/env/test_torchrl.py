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


def test_dict_observation_specs_and_rollout():
    """``obs_format="dict"``: TorchRL's wrapper builds a composite spec with both blocks."""
    pz = coop_loc_env.parallel_env("active_hallway", n_robots=2, max_cycles=4, n_particles=100,
                                   reward_terms_dict=False, obs_format="dict",
                                   belief_map_cells=8)
    env = PettingZooWrapper(env=pz, use_mask=True, done_on_any=False, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(10)
    obs = td["next", "robot", "observation"]
    assert td.batch_size == torch.Size([4])
    assert obs["belief_map"].shape == (4, 2, 10, 8, 8)
    assert obs["vector"].shape[:2] == (4, 2)
    torch.testing.assert_close(obs["belief_map"][..., :8, :, :].sum(dim=(-3, -2, -1)),
                               torch.ones(4, 2))  # each robot's belief mass sums to 1
    env.close()


@pytest.mark.parametrize("scenario", coop_loc_env.list_scenarios())
def test_wrapper_with_default_arguments_on_every_scenario(scenario):
    env = PettingZooWrapper(env=coop_loc_env.parallel_env(scenario), use_mask=True)
    check_env_specs(env, seed=0)
    td = env.rollout(50)
    assert td.batch_size == torch.Size([50])
    assert torch.isfinite(td["next", "robot", "reward"]).all()
    env.close()


@pytest.mark.parametrize("scenario", coop_loc_env.list_scenarios())
def test_torchrl_env_specs_and_rollout_on_every_scenario(scenario):
    env = coop_loc_env.torchrl_env(scenario, seed=0)
    check_env_specs(env, seed=0)
    td = env.rollout(50)
    n = len(env.agents)
    assert td.batch_size == torch.Size([50])
    assert td["next", "robot", "observation"].shape[:2] == (50, n)
    assert torch.isfinite(td["next", "robot", "info", "position_error"]).all()
    env.close()


def test_torchrl_env_steps_like_the_parallel_env():
    kw = dict(n_robots=3, max_cycles=8, team=MIXED, n_particles=100)
    env = coop_loc_env.torchrl_env("outdoor_terrain", seed=4, **kw)
    pz = coop_loc_env.parallel_env("outdoor_terrain", **kw)
    obs, infos = pz.reset(seed=4)
    td = env.reset()
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(td["robot", "observation"].numpy(),
                                  np.stack(list(obs.values())))
    for t in range(8):
        act = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        td["robot", "action"] = torch.from_numpy(act)
        td = env.step(td)
        obs, rew, term, trunc, infos = pz.step(dict(zip(pz.agents, act, strict=True)))
        nxt = td["next", "robot"]
        np.testing.assert_array_equal(nxt["observation"].numpy(), np.stack(list(obs.values())))
        np.testing.assert_allclose(nxt["reward"][:, 0].numpy(), list(rew.values()), rtol=1e-6)
        np.testing.assert_allclose(nxt["info", "position_error"].numpy(),
                                   [i["position_error"] for i in infos.values()], rtol=1e-6)
        assert nxt["truncated"][:, 0].tolist() == [t == 7] * 3
        assert td["next", "done"].item() == (t == 7) == td["next", "truncated"].item()
        assert not td["next", "terminated"].item()
        td = td["next"].clone()
    assert torch.isnan(nxt["info", "particle_spread"][0]) and torch.isfinite(
        nxt["info", "particle_spread"][1])


def test_torchrl_env_tip_over_masks_the_robot_and_the_team_drives_on(steep_and_flat):
    env = coop_loc_env.torchrl_env("outdoor_terrain", seed=0, n_robots=2, max_cycles=4,
                                   start_poses=steep_and_flat)
    td = env.rollout(10)
    robot = td["next", "robot"]
    assert td.batch_size == torch.Size([4])
    assert robot["terminated"][:, 0, 0].tolist() == [True] * 4
    assert robot["terminated"][:, 1, 0].tolist() == [False] * 4
    assert robot["truncated"][:, 1, 0].tolist() == [False, False, False, True]
    assert robot["mask"][:, 0].tolist() == [False] * 4
    assert robot["mask"][:, 1].tolist() == [True, True, True, False]
    assert robot["reward"][0, 0, 0] <= -10.0  # the tip-over penalty, then nothing
    assert robot["reward"][1:, 0, 0].tolist() == [0.0] * 3
    assert (robot["observation"][1:, 0] == 0).all()
    assert torch.isnan(robot["info", "position_error"][1:, 0]).all()
    assert td["next", "done"][:, 0].tolist() == [False, False, False, True]
    assert not td["next", "terminated"].any() and td["next", "truncated"][-1].item()


def test_torchrl_env_info_keys_and_seeding():
    env = coop_loc_env.torchrl_env("rendezvous", seed=1, info_keys=["coverage"], max_cycles=5)
    assert list(env.observation_spec["robot", "info"].keys()) == ["coverage"]

    def forward(td):
        return td.set(("robot", "action"), torch.full((4, 2), 0.5))

    first = env.rollout(5, forward)
    env.rollout(3, forward)  # the next episode differs ...
    env.set_seed(1)
    again = env.rollout(5, forward)  # ... and seeding again repeats the first
    torch.testing.assert_close(first["next", "robot", "observation"],
                               again["next", "robot", "observation"])
    with pytest.raises(ValueError, match="'pose_cov'"):
        coop_loc_env.torchrl_env("rendezvous", info_keys=["pose_cov"])
    with pytest.raises(ValueError, match="'nope'"):
        coop_loc_env.torchrl_env("rendezvous", info_keys=["nope"])
