"""The per-agent-slot SB3 VecEnv adapter: truncation flags, terminal observations, padding."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

import coop_loc_env
from policies.learning.env_copies import EnvCopies
from policies.learning.sb3_vec_env import ParallelEnvVecEnv
from policies.learning.vec_env import make_env_fn


def _venv(n_envs=1, n_procs=1, **overrides):
    return ParallelEnvVecEnv(
        make_env_fn("outdoor_terrain", **overrides), n_envs=n_envs, n_procs=n_procs
    )


def test_three_step_episode_truncation_and_terminal_observation():
    overrides = dict(n_robots=2, max_cycles=3)
    venv = _venv(**overrides)
    ref = coop_loc_env.parallel_env("outdoor_terrain", **overrides)
    try:
        assert venv.num_envs == 2
        venv.seed(11)
        obs = venv.reset()
        ref_obs, _ = ref.reset(seed=11)
        np.testing.assert_array_equal(obs, np.stack([ref_obs["robot_0"], ref_obs["robot_1"]]))
        actions = np.array([[0.5, 0.2], [-0.3, 0.4]], dtype=np.float32)
        for t in range(3):
            obs, rew, done, infos = venv.step(actions)
            ref_obs, ref_rew, _, ref_trunc, _ = ref.step(
                {"robot_0": actions[0], "robot_1": actions[1]}
            )
            np.testing.assert_allclose(rew, [ref_rew["robot_0"], ref_rew["robot_1"]], rtol=1e-6)
            if t < 2:
                assert not done.any()
                assert all("terminal_observation" not in i for i in infos)
                np.testing.assert_array_equal(obs[1], ref_obs["robot_1"])
        assert done.tolist() == [True, True]
        assert all(ref_trunc.values())
        for i, agent in enumerate(("robot_0", "robot_1")):
            assert infos[i]["TimeLimit.truncated"] is True  # PPO bootstraps the value
            np.testing.assert_array_equal(infos[i]["terminal_observation"], ref_obs[agent])
            assert infos[i]["episode"]["l"] == 3
        # auto-reset: the returned observation is the first of the next episode
        next_obs, _ = ref.reset()
        np.testing.assert_array_equal(obs[0], next_obs["robot_0"])
        assert not np.array_equal(obs[0], infos[0]["terminal_observation"])
    finally:
        venv.close()


class _StubEnv:
    """Two agents; ``robot_1`` terminates at step 1, the episode truncates at step 3."""

    possible_agents = ["robot_0", "robot_1"]
    render_mode = None

    def __init__(self) -> None:
        self._obs = spaces.Box(-10, 10, (2,), np.float32)
        self._act = spaces.Box(-1, 1, (2,), np.float32)
        self.agents: list[str] = []
        self.t = 0
        self.received: list[dict] = []

    def observation_space(self, agent):
        return self._obs

    def action_space(self, agent):
        return self._act

    def _o(self, i):
        return np.array([self.t, i + 1], dtype=np.float32)

    def reset(self, seed=None, options=None):
        self.t = 0
        self.agents = list(self.possible_agents)
        return {a: self._o(i) for i, a in enumerate(self.possible_agents)}, {}

    def step(self, actions):
        if set(actions) != set(self.agents):
            raise ValueError(f"actions for {sorted(actions)}, live agents {self.agents}")
        self.received.append(actions)
        self.t += 1
        live = list(self.agents)
        idx = {a: i for i, a in enumerate(self.possible_agents)}
        obs = {a: self._o(idx[a]) for a in live}
        rew = {a: float(idx[a] + 1) for a in live}
        term = {a: a == "robot_1" and self.t == 1 for a in live}
        trunc = {a: self.t >= 3 for a in live}
        self.agents = [a for a in live if not (term[a] or trunc[a])]
        return obs, rew, term, trunc, {a: {"t": self.t} for a in live}

    def close(self):
        pass


def test_early_termination_gives_done_once_then_padding_until_copy_reset():
    copies = EnvCopies(_StubEnv, 1)
    copies.reset([None])
    act = np.ones((2, 2), dtype=np.float32)
    obs, rew, done, infos = copies.step(act)  # step 1: robot_1 tips over
    assert done.tolist() == [False, True]
    assert infos[1]["TimeLimit.truncated"] is False  # terminated: no bootstrap
    np.testing.assert_array_equal(infos[1]["terminal_observation"], [1, 2])
    assert infos[1]["episode"] == {"r": 2.0, "l": 1, "t": infos[1]["episode"]["t"]}
    np.testing.assert_array_equal(obs[1], [0, 0])
    obs, rew, done, infos = copies.step(act)  # step 2: robot_1 is padding
    assert done.tolist() == [False, False]
    assert rew[1] == 0.0 and infos[1] == {"padding": True}
    np.testing.assert_array_equal(obs[1], [0, 0])
    assert list(copies.envs[0].received[-1]) == ["robot_0"]  # padding action ignored
    obs, rew, done, infos = copies.step(act)  # step 3: truncation, copy resets
    assert done.tolist() == [True, True]
    assert infos[0]["TimeLimit.truncated"] is True
    np.testing.assert_array_equal(infos[0]["terminal_observation"], [3, 1])
    assert infos[0]["episode"]["r"] == 3.0 and infos[0]["episode"]["l"] == 3
    assert infos[1]["padding"] and infos[1]["TimeLimit.truncated"] is False
    np.testing.assert_array_equal(infos[1]["terminal_observation"], [0, 0])
    np.testing.assert_array_equal(obs, [[0, 1], [0, 2]])  # the new episode's first obs
    obs, rew, done, infos = copies.step(act)  # both slots live again
    assert rew.tolist() == [1.0, 2.0] and done.tolist() == [False, True]


def test_real_env_tip_over_is_a_termination_then_padding(steep_and_flat):
    steep, flat = steep_and_flat
    venv = _venv(n_robots=2, max_cycles=3, start_poses=(steep, flat))
    try:
        venv.seed(0)
        venv.reset()
        act = np.full((2, 2), 0.1, dtype=np.float32)
        _, rew, done, infos = venv.step(act)
        assert done.tolist() == [True, False]
        assert infos[0]["tipped_over"] and infos[0]["TimeLimit.truncated"] is False
        assert infos[0]["terminal_observation"].shape == venv.observation_space.shape
        assert rew[0] <= -10.0  # tip-over penalty
        obs, rew, done, infos = venv.step(act)  # robot_0 is padding, robot_1 drives on
        assert done.tolist() == [False, False] and infos[0] == {"padding": True}
        assert rew[0] == 0.0 and not obs[0].any() and obs[1].any()
        _, _, done, infos = venv.step(act)
        assert done.tolist() == [True, True]
        assert infos[0]["padding"] and infos[0]["TimeLimit.truncated"] is False
        assert infos[1]["TimeLimit.truncated"] is True
    finally:
        venv.close()


def test_two_processes_match_one_process():
    kw = dict(n_robots=2, max_cycles=4)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (6, 8, 2)).astype(np.float32)
    runs = []
    for procs in (1, 2):
        venv = _venv(n_envs=4, n_procs=procs, **kw)
        try:
            venv.seed(5)
            out = [venv.reset()]
            for a in actions:
                obs, rew, done, infos = venv.step(a)
                out += [obs, rew, done.astype(float)]
            assert venv.get_attr("scenario", indices=[0, 7]) == ["outdoor_terrain"] * 2
            assert venv.env_method("action_space", "robot_0", indices=[3])[0].shape == (2,)
            runs.append(out)
        finally:
            venv.close()
    for a, b in zip(*runs, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(runs[0][0][0], runs[0][0][2])  # copies seeded differently


def test_bad_arguments_raise_value_error():
    fn = make_env_fn("outdoor_terrain", n_robots=2)
    with pytest.raises(ValueError, match="n_envs"):
        ParallelEnvVecEnv(fn, n_envs=0)
    with pytest.raises(ValueError, match="n_procs"):
        ParallelEnvVecEnv(fn, n_envs=1, n_procs=2)
    with pytest.raises(ValueError, match="n_robotz"):
        make_env_fn("outdoor_terrain", n_robotz=2)


def test_dict_observation_trains_a_multi_input_policy():
    """``obs_format="dict"``: the adapter stacks both blocks per slot, SB3's MultiInputPolicy
    learns from them, and an early termination leaves zero-filled dict padding."""
    from stable_baselines3 import PPO

    overrides = dict(n_robots=2, max_cycles=4, n_particles=100, obs_format="dict",
                     belief_map_cells=8)
    venv = ParallelEnvVecEnv(make_env_fn("active_hallway", **overrides), n_envs=1)
    try:
        assert isinstance(venv.observation_space, spaces.Dict)
        venv.seed(3)
        obs = venv.reset()
        ref = coop_loc_env.parallel_env("active_hallway", **overrides)
        ref_obs, _ = ref.reset(seed=3)
        for key in ("vector", "belief_map"):
            np.testing.assert_array_equal(obs[key][1], ref_obs["robot_1"][key])
        assert obs["belief_map"].shape == (2, 10, 8, 8)
        model = PPO("MultiInputPolicy", venv, n_steps=8, batch_size=8, n_epochs=1, seed=0)
        model.learn(16)
        action, _ = model.predict(obs, deterministic=True)
        assert action.shape == (2, 2) and np.all(np.abs(action) <= 1)
        zeros = EnvCopies(make_env_fn("active_hallway", **overrides), 1)._zeros()
        assert set(zeros) == {"vector", "belief_map"} and not zeros["belief_map"].any()
    finally:
        venv.close()
