"""vector_env: world i of a batch seeded s replays parallel_env seeded s + i exactly;
autoreset, the tip-over mask, array infos and bad input."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env import RobotSpec

MIXED = (RobotSpec(estimator="ekf"), RobotSpec(estimator="mcl", has_gps=False))
READING_FIELDS = ("odometry", "gps_mask", "gps_xy", "satellites", "compass", "pitch",
                  "ranges")


def _stack(obs: dict) -> np.ndarray | dict:
    rows = list(obs.values())
    if isinstance(rows[0], dict):
        return {k: np.stack([r[k] for r in rows]) for k in rows[0]}
    return np.stack(rows)


def _assert_obs_equal(batch_row, ref) -> None:
    if isinstance(ref, dict):
        assert set(batch_row) == set(ref)
        for key in ref:
            np.testing.assert_array_equal(batch_row[key], ref[key], err_msg=key)
    else:
        np.testing.assert_array_equal(batch_row, ref)


def _replay(scenario: str, num_envs: int, steps: int, seed: int = 5, **kw) -> None:
    """Step the batch and one parallel env per world under the same random actions;
    every observation, reward, flag, belief and reading must be the same bits."""
    vec = coop_loc_env.vector_env(scenario, num_envs=num_envs, **kw)
    refs = [coop_loc_env.parallel_env(scenario, **kw) for _ in range(num_envs)]
    obs, _ = vec.reset(seed=seed)
    for i, env in enumerate(refs):
        ref_obs, _ = env.reset(seed=seed + i)
        _assert_obs_equal(_row(obs, i), _stack(ref_obs))
    rng = np.random.default_rng(0)
    n = vec.n_robots
    contacts = 0
    for _ in range(steps):
        act = rng.uniform(-1, 1, (num_envs, n, 2)).astype(np.float32)
        act[..., 0] = np.abs(act[..., 0])  # forward: into each other
        obs, rewards, term, trunc, infos = vec.step(act)
        for i, env in enumerate(refs):
            r_obs, r_rew, r_term, r_trunc, r_infos = env.step(
                {a: act[i, k] for k, a in enumerate(env.possible_agents)})
            _assert_obs_equal(_row(obs, i), _stack(r_obs))
            np.testing.assert_array_equal(rewards[i], list(r_rew.values()))
            assert term[i].tolist() == list(r_term.values())
            assert trunc[i].tolist() == list(r_trunc.values())
            np.testing.assert_array_equal(vec.envs[i].beliefs.mean, env.beliefs.mean)
            np.testing.assert_array_equal(vec.envs[i].beliefs.cov, env.beliefs.cov)
            for name in READING_FIELDS:
                np.testing.assert_array_equal(getattr(vec.envs[i].last_readings, name),
                                              getattr(env.last_readings, name), err_msg=name)
            for k, a in enumerate(env.possible_agents):
                assert infos["position_error"][i, k] == r_infos[a]["position_error"]
                assert infos["reward_localization"][i, k] == r_infos[a]["reward_localization"]
            contacts += int(infos["collisions"][i].sum())
    return contacts


def _row(obs, i):
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


def test_rendezvous_ekf_worlds_replay_parallel_env_bit_for_bit():
    # long enough for robots to touch each other or the trees: exact after contacts too
    start = ((10.0, 10.0, 0.0), (11.5, 10.0, np.pi), (20.0, 20.0, 0.0), (30.0, 30.0, 0.0))
    contacts = _replay("rendezvous", 3, 60, max_cycles=100, start_poses=start)
    assert contacts > 0


@pytest.mark.parametrize("scenario, kw", [
    ("active_hallway", {"n_particles": 120, "obs_format": "dict"}),
    ("outdoor_terrain", {"team": MIXED, "n_robots": 2, "n_particles": 100}),
    ("outdoor_terrain", {"estimator": "mle", "n_robots": 2}),
], ids=["mcl-dict", "ekf+mcl", "mle"])
def test_every_estimator_and_obs_format_replays_parallel_env(scenario, kw):
    _replay(scenario, 2, 8, seed=11, max_cycles=50, **kw)


def test_shapes_and_default_infos():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=4)
    obs, infos = vec.reset(seed=0)
    dim = vec.single_observation_space.shape[0]
    assert obs.shape == (4, 4, dim) and obs.dtype == np.float32
    assert vec.observation_space.contains(obs) and vec.action_space.shape == (4, 4, 2)
    assert infos["mask"].all()
    obs, rew, term, trunc, infos = vec.step(np.zeros((4, 4, 2)))
    assert rew.shape == term.shape == trunc.shape == (4, 4)
    assert {"mask", "position_error", "heading_error", "collisions", "in_contact",
            "tipped_over", "reward_localization", "reward_team_localization"} <= set(infos)
    assert "coverage" not in infos and "pose_cov" not in infos  # the costly ones: opt-in
    terms = sum(v for k, v in infos.items() if k.startswith("reward_"))
    np.testing.assert_allclose(terms, rew, rtol=0, atol=1e-12)


def test_opt_in_infos_equal_parallel_env_infos():
    keys = ("true_pose", "pose_cov", "gps_fix", "coverage", "map_rmse", "covered_cells")
    vec = coop_loc_env.vector_env("outdoor_terrain", num_envs=2, n_robots=2, info_keys=keys)
    ref = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2)
    vec.reset(seed=3)
    ref.reset(seed=4)
    act = np.full((2, 2, 2), 0.7)
    for _ in range(3):
        _, _, _, _, infos = vec.step(act)
        _, _, _, _, r_infos = ref.step({a: act[1, k] for k, a in enumerate(ref.agents)})
    assert set(infos) == {"mask", *keys}
    for k, a in enumerate(ref.possible_agents):
        for key in keys:
            np.testing.assert_array_equal(infos[key][1, k], r_infos[a][key], err_msg=key)


def test_unknown_info_key_refused_at_reset():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=1, info_keys=("position_eror",))
    with pytest.raises(ValueError, match="position_eror"):
        vec.reset(seed=0)


def test_autoreset_same_step_hands_back_final_obs():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=2, max_cycles=3)
    ref = coop_loc_env.parallel_env("rendezvous", max_cycles=3)
    vec.reset(seed=7)
    ref.reset(seed=8)
    act = np.full((2, 4, 2), 0.5)
    for _ in range(3):
        obs, rew, term, trunc, infos = vec.step(act)
        r_obs, r_rew, *_ = ref.step({a: act[1, k] for k, a in enumerate(ref.agents)})
    assert trunc.all() and not term.any()
    assert infos["_final_obs"].tolist() == [True, True]
    np.testing.assert_array_equal(infos["final_obs"][1], _stack(r_obs))
    np.testing.assert_array_equal(rew[1], list(r_rew.values()))
    new_obs, _ = ref.reset()  # the world goes on with its own stream, unseeded
    np.testing.assert_array_equal(obs[1], _stack(new_obs))
    assert vec.reset_count.tolist() == [2, 2] and vec.mask.all()
    obs, _, _, trunc, infos = vec.step(act)  # the new episode runs
    r_obs, *_ = ref.step({a: act[1, k] for k, a in enumerate(ref.agents)})
    assert not trunc.any() and "_final_obs" not in infos
    np.testing.assert_array_equal(obs[1], _stack(r_obs))


def test_tipped_robot_is_masked_and_its_actions_ignored(steep_and_flat):
    vec = coop_loc_env.vector_env("outdoor_terrain", num_envs=2, n_robots=2, max_cycles=4,
                                  start_poses=steep_and_flat)
    vec.reset(seed=0)
    act = np.full((2, 2, 2), 0.5)
    _, rew, term, _, infos = vec.step(act)
    assert term[:, 0].all() and not term[:, 1].any()  # robot 0 tipped in both worlds
    assert infos["mask"].all() and infos["tipped_over"][:, 0].all()
    assert (rew[:, 0] <= -vec.config.tip_over_penalty).all()
    assert vec.mask[:, 0].tolist() == [False, False] and vec.mask[:, 1].all()
    act[:, 0] = np.nan  # a robot that is out: its action is not read
    _, rew, term, trunc, infos = vec.step(act)
    assert not infos["mask"][:, 0].any() and (rew[:, 0] == 0).all() and term[:, 0].all()
    for _ in range(2):
        _, _, _, trunc, infos = vec.step(act)
    assert trunc[:, 1].all() and infos["_final_obs"].all()
    assert vec.mask.all()  # both worlds reset: every robot drives again


def test_bad_action_names_world_and_robot_and_batch_stays_usable():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=20, max_cycles=50)
    ref = coop_loc_env.parallel_env("rendezvous", max_cycles=50)
    vec.reset(seed=0)
    ref.reset(seed=17)
    bad = np.zeros((20, 4, 2))
    bad[17, 2] = (np.nan, 0.0)
    with pytest.raises(ValueError, match=r"robot 2 in world 17 contains NaN"):
        vec.step(bad)
    bad[17, 2] = (1.5, 0.0)
    with pytest.raises(ValueError, match=r"robot 2 in world 17 is outside \[-1, 1\]"):
        vec.step(bad)
    with pytest.raises(ValueError, match=r"shape \(20, 4, 2\)"):
        vec.step(np.zeros((20, 4)))
    with pytest.raises(ValueError, match="real numbers"):
        vec.step(np.full((20, 4, 2), "a"))
    good = np.full((20, 4, 2), 0.3)
    obs, *_ = vec.step(good)  # no world moved on the refused steps
    r_obs, *_ = ref.step({a: good[17, k] for k, a in enumerate(ref.agents)})
    np.testing.assert_array_equal(obs[17], _stack(r_obs))
    assert vec.envs[17].step_count == 1


@pytest.mark.parametrize("num_envs", [0, -2, 1.5, True])
def test_bad_num_envs_refused(num_envs):
    with pytest.raises(ValueError, match="num_envs"):
        coop_loc_env.vector_env("rendezvous", num_envs=num_envs)


def test_step_before_reset_refused():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=2)
    with pytest.raises(ValueError, match="before reset"):
        vec.step(np.zeros((2, 4, 2)))


def test_without_autoreset_an_ended_world_waits_for_its_reset():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=3, max_cycles=2, autoreset=False)
    ref = coop_loc_env.parallel_env("rendezvous", max_cycles=2)
    vec.reset(seed=0)
    ref.reset(seed=1)
    act = np.zeros((3, 4, 2))
    for _ in range(2):
        _, _, _, trunc, infos = vec.step(act)
        ref.step({a: act[1, k] for k, a in enumerate(ref.agents)})
    assert trunc.all() and "_final_obs" not in infos and not vec.mask.any()
    with pytest.raises(ValueError, match="world 0 has ended"):
        vec.step(act)
    obs, infos = vec.reset(worlds=np.array([True, True, True]))
    np.testing.assert_array_equal(obs[1], _stack(ref.reset()[0]))  # unseeded: own stream
    assert infos["mask"].all() and vec.reset_count.tolist() == [2, 2, 2]
    vec.step(act)
    with pytest.raises(ValueError, match="worlds must be indices"):
        vec.reset(worlds=[3])


def test_a_list_of_seeds_seeds_each_world_and_bad_seeds_are_refused():
    vec = coop_loc_env.vector_env("rendezvous", num_envs=2)
    obs, _ = vec.reset(seed=[9, 3])
    ref = coop_loc_env.parallel_env("rendezvous")
    np.testing.assert_array_equal(obs[0], _stack(ref.reset(seed=9)[0]))
    np.testing.assert_array_equal(obs[1], _stack(ref.reset(seed=3)[0]))
    for bad in ([1], [1, -2], -1, 1.5):
        with pytest.raises(ValueError, match="seed"):
            vec.reset(seed=bad)


@pytest.mark.parametrize("scenario", coop_loc_env.list_scenarios())
def test_every_scenario_replays_parallel_env(scenario):
    _replay(scenario, 2, 3, seed=1, n_particles=100)
