"""The rendezvous scenario, its scripted baselines (gather, infogain), teammate observations
and the uncertainty reward shaping."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.observations import teammate_features
from policies.learning.loader import make_policy

FAST = {"max_cycles": 60, "false_positive_prob": 0.0}


def test_rendezvous_config():
    cfg = coop_loc_env.make_config("rendezvous")
    assert cfg.n_robots == 4 and cfg.start_region is None and cfg.steep_patches == 0
    assert cfg.init_pos_std == 2.0 and cfg.max_cycles == 400
    assert [cfg.robot_spec(i).has_gps for i in range(4)] == [True, False, True, False]
    assert coop_loc_env.env_id("rendezvous") == "coop_loc/Rendezvous-v0"


class _TruthReader:
    """A policy that (wrongly) reads the true poses: the control of the test below."""

    name = "cheat"

    def reset(self, env, seed=None):
        self.env = env

    def act(self, obs):
        x = self.env.world.poses[:, 0]
        return {a: np.array([np.tanh(x[self.env.agent_name_mapping[a]]), 0.0], dtype=np.float32)
                for a in self.env.agents}


@pytest.mark.parametrize("spec", ["gather", "infogain", "seek", "cheat"])
def test_baselines_never_read_the_truth(spec, actions_with_shifted_truth):
    """Shifting the true poses (nothing a robot could know) leaves the actions unchanged."""
    env = coop_loc_env.parallel_env("rendezvous", **FAST)
    policy = _TruthReader() if spec == "cheat" else make_policy(spec)
    obs, _ = env.reset(seed=3)
    policy.reset(env, seed=3)
    rng = np.random.default_rng(0)
    differs = []
    for t in range(41):
        if t % 10 == 0:  # infogain replans on these steps
            for agent in env.agents:
                env.camera_readings(agent)  # the camera's lazily built records, taken now
            before, after = actions_with_shifted_truth(env, policy, obs, rng)
            differs.append(any(not np.array_equal(before[a], after[a]) for a in env.agents))
        obs, *_ = env.step(policy.act(obs))
    assert any(differs) == (spec == "cheat")


def test_teammate_features_by_hand():
    mean = np.array([[0.0, 0.0, np.pi / 2], [0.0, 4.0, 0.0], [3.0, 0.0, 0.0], [0.0, -8.0, 0.0]])
    cov = np.repeat(np.diag([0.04, 0.04, 0.01])[None], 4, axis=0)
    cov[3, :2, :2] = np.eye(2) * 4.0
    gps = np.array([True, False, True, False])
    live = np.array([True, True, True, True])
    f = teammate_features(mean, cov, gps, live, scale=8.0)
    # robot 0 (heading north): nearest GPS mate is 2 (east: bearing -90 deg), nearest
    # no-GPS mate is 1 (north: bearing 0) at 4 m, not 3 at 8 m.
    np.testing.assert_allclose(f[0], [1, 1, 0, -1, 3 / 8, np.log10(0.2),
                                      1, 1, 0, 0.5, np.log10(0.2)], atol=1e-12)
    live[1] = False  # a robot out of the episode is skipped: 3 is then the nearest
    f = teammate_features(mean, cov, gps, live, scale=8.0)
    np.testing.assert_allclose(f[0, 6:], [1, -1, 0, 1.0, np.log10(2.0)], atol=1e-12)
    # a team without GPS: the GPS slot is absent for everyone
    lone = teammate_features(mean[:2], cov[:2], np.array([False, False]), np.ones(2, bool), 8.0)
    assert np.all(lone[:, 1:6] == 0.0)  # nobody with GPS: the slot is absent (all zeros)


def test_teammate_obs_block_and_shaping_terms():
    env = coop_loc_env.parallel_env("rendezvous", teammate_obs=True, reward_team_weight=0.5,
                                    reward_uncertainty_weight=2.0, reward_terms_dict=True,
                                    **FAST)
    names = env.observations.names
    assert names[names.index("last_w") + 1] == "team_own_gps"
    obs, infos = env.reset(seed=1)
    col = names.index("team_own_gps")
    assert [obs[a][col] for a in env.agents] == [1.0, 0.0, 1.0, 0.0]
    half = {a: 0.5 * np.log(np.linalg.det(infos[a]["pose_cov"][:2, :2])) for a in env.agents}
    shaped = False
    for _ in range(30):
        obs, rewards, _, _, infos = env.step({a: np.array([1.0, 0.0], np.float32)
                                              for a in env.agents})
        team = -0.5 * np.mean([infos[a]["position_error"] for a in env.agents])
        for a in env.agents:
            terms = infos[a]["reward_terms"]
            now = 0.5 * np.log(np.linalg.det(infos[a]["pose_cov"][:2, :2]))
            assert terms["uncertainty"] == pytest.approx(-2.0 * (now - half[a]), abs=1e-9)
            assert terms["team_localization"] == pytest.approx(team)
            assert rewards[a] == pytest.approx(sum(terms.values()))
            shaped |= terms["uncertainty"] > 0.1  # a GPS fix shrank the belief
            half[a] = now
    assert shaped


def test_scenario_training_defaults_reach_train_cli():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "scripts" / "train.py"
    spec = importlib.util.spec_from_file_location("train_cli", path)
    train_cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(train_cli)
    from coop_loc_env.scenarios import training_defaults

    carried = training_defaults("rendezvous")
    assert carried  # the scenario carries its own settings
    args = train_cli.parse_args(["--scenario", "rendezvous", "--out", "x"])
    for key, value in carried.items():
        assert getattr(args, key) == value
    plain = train_cli.parse_args(["--scenario", "outdoor_terrain", "--out", "x"])
    assert plain.learning_rate == train_cli.build_parser().get_default("learning_rate")
    given = train_cli.parse_args(["--scenario", "rendezvous", "--out", "x", "--gamma", "0.9"])
    assert given.gamma == 0.9
    hallway = train_cli.config_from_args(
        train_cli.parse_args(["--scenario", "active_hallway", "--out", "x"]))
    assert hallway.env_overrides()["obs_format"] == "dict"  # the belief map, by default
    flat = train_cli.config_from_args(train_cli.parse_args(
        ["--scenario", "active_hallway", "--out", "x", "--obs-format", "flat"]))
    assert flat.env_overrides()["obs_format"] == "flat"


def test_dagger_collection_labels_the_actor_states():
    """With an actor, the actor drives and the teacher only labels."""
    from functools import partial

    from policies.learning.imitation import collect_demonstrations
    from policies.scripted import GatherPolicy

    env_fn = partial(coop_loc_env.parallel_env, "rendezvous", max_cycles=30,
                     false_positive_prob=0.0, start_poses=((5, 5, 0), (35, 35, 0),
                                                           (5, 35, 0), (35, 5, 0)))
    still = collect_demonstrations(env_fn, GatherPolicy(), 1, seed=0,
                                   actor=lambda batch: np.zeros((len(batch), 2)))
    driven = collect_demonstrations(env_fn, GatherPolicy(), 1, seed=0)
    assert np.abs(still["actions"][:, 0]).max() > 0.5  # the teacher wants to drive ...
    col = env_fn().observations.names.index("last_v")
    assert np.all(still["obs"][:, col] == 0.0)  # ... but the actor stood still
    assert driven["obs"][:, col].max() > 0.5


def test_dagger_rounds_need_a_teacher():
    from policies.learning.training import TrainConfig

    with pytest.raises(ValueError, match="dagger_rounds"):
        TrainConfig(out="x", dagger_rounds=2).validate()
    with pytest.raises(ValueError, match="dagger_rounds"):
        TrainConfig(out="x", dagger_rounds=-1, bc_from="gather").validate()


def test_bc_from_none_turns_cloning_off():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "scripts" / "train.py"
    spec = importlib.util.spec_from_file_location("train_cli", path)
    train_cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(train_cli)
    args = train_cli.parse_args(["--scenario", "rendezvous", "--out", "x", "--bc-from", "none"])
    cfg = train_cli.config_from_args(args)
    assert cfg.bc_from is None and cfg.dagger_rounds == 0
    cfg.validate()
    cfg = train_cli.config_from_args(train_cli.parse_args(["--scenario", "rendezvous",
                                                           "--out", "x"]))
    assert cfg.bc_from == "gather" and cfg.dagger_rounds > 0
