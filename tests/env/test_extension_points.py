"""Extension by registration, from outside the package: an estimator backend with an
option of its own, an observation block, a reward term, a scenario with hooks."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.backends import BACKEND_OPTIONS, BACKENDS, register_backend
from coop_loc_env.backends.base import (
    EstimatorBackend,
    gaussian_features,
    noisy_start,
    team_odometry,
)
from coop_loc_env.extras import BackendOptions, is_number, option
from coop_loc_env.obs_blocks import OBS_BLOCKS, ObsBlock, register_obs_block
from coop_loc_env.rewards import REWARD_TERMS, RewardTerm, register_reward_term
from coop_loc_env.scenarios import unregister_scenario


@pytest.fixture
def registries():
    """Leave the registries as they were (the tests register into them)."""
    saved = [(d, dict(d)) for d in (BACKENDS, BACKEND_OPTIONS, OBS_BLOCKS, REWARD_TERMS)]
    yield
    for registry, copy in saved:
        registry.clear()
        registry.update(copy)


class DeadReckoning(EstimatorBackend):
    """Odometry only; the position variance grows by ``extras["dr_growth"]`` a step."""

    feature_size = 10
    options = BackendOptions({
        "dr_growth": option(lambda v: is_number(v) and v >= 0, "a number >= 0"),
    })

    def __init__(self, cfg, robots, world=None) -> None:
        self.cfg, self.robots = cfg, np.asarray(robots)
        self.growth = cfg.extras.get("dr_growth", 0.01)

    def reset(self, true_poses, rng) -> None:
        self._mean, std = noisy_start(self.cfg, true_poses, self.robots, rng)
        self._cov = np.repeat(np.diag(std**2)[None], len(self.robots), axis=0)

    def step(self, readings, active) -> dict[str, int]:
        v, w, dt = team_odometry(self.cfg, readings, self.robots, active)
        for vs, ws in zip(v, w, strict=True):
            th = self._mean[:, 2]
            self._mean[:, 0] += vs * np.cos(th) * dt
            self._mean[:, 1] += vs * np.sin(th) * dt
            self._mean[:, 2] += ws * dt
        self._cov[:, 0, 0] += self.growth
        self._cov[:, 1, 1] += self.growth
        return {}

    def mean(self) -> np.ndarray:
        return self._mean

    def cov(self) -> np.ndarray:
        return self._cov

    def features(self) -> np.ndarray:
        return gaussian_features(self._mean, self._cov, self.cfg.world_size)


def _drive(env, steps):
    out = None
    for _ in range(steps):
        out = env.step({a: np.array([0.5, 0.1], np.float32) for a in env.agents})
    return out


def test_a_registered_backend_runs_an_episode_with_its_own_option(registries):
    with pytest.raises(ValueError, match="'dead_reckoning'"):  # not registered yet
        coop_loc_env.make_config("outdoor_terrain", estimator="dead_reckoning")
    register_backend("dead_reckoning", DeadReckoning)
    env = coop_loc_env.parallel_env(estimator="dead_reckoning", max_cycles=5,
                                    extras={"dr_growth": 0.5})
    assert isinstance(env.backends[0], DeadReckoning)
    _, infos = env.reset(seed=0)
    start_var = infos["robot_0"]["pose_cov"][0, 0]
    steps = 0
    while env.agents:
        _, _, _, _, infos = _drive(env, 1)
        steps += 1
    assert steps == 5
    assert infos["robot_0"]["pose_cov"][0, 0] == pytest.approx(start_var + 5 * 0.5)
    with pytest.raises(ValueError, match="'dr_growht'"):  # unknown keys are still refused
        coop_loc_env.make_config("outdoor_terrain", estimator="dead_reckoning",
                                 extras={"dr_growht": 0.5})
    with pytest.raises(ValueError, match=r"extras\['dr_growth'\] must be a number >= 0"):
        coop_loc_env.make_config("outdoor_terrain", extras={"dr_growth": -1.0})
    # A team mixes it with a shipped estimator; each backend reads its own options.
    mixed = coop_loc_env.parallel_env(
        n_robots=2, max_cycles=3, n_particles=100, extras={"dr_growth": 0.0,
                                                           "mcl_detection_reset": 0.1},
        team=(coop_loc_env.RobotSpec(estimator="dead_reckoning"),
              coop_loc_env.RobotSpec(estimator="mcl")))
    mixed.reset(seed=1)
    _drive(mixed, 2)


class EstimatedPosition(ObsBlock):
    """The estimated position in tens of metres."""

    def __init__(self, setup) -> None:
        super().__init__(setup, ["est_x_dam", "est_y_dam"])

    def observe(self, x, out) -> None:
        out[:] = x.est_mean[:, :2] / 10.0


def test_a_registered_observation_block_extends_the_space_and_the_vector(registries):
    with pytest.raises(ValueError, match="unknown observation block 'est_position'"):
        coop_loc_env.make_config("outdoor_terrain", extra_obs_blocks=("est_position",))
    register_obs_block("est_position", EstimatedPosition)
    plain = coop_loc_env.parallel_env(max_cycles=4)
    env = coop_loc_env.parallel_env(max_cycles=4, extra_obs_blocks=["est_position"])
    base = plain.observation_space("robot_0").shape[0]
    assert env.observation_space("robot_0").shape == (base + 2,)
    assert env.observations.names[-2:] == ["est_x_dam", "est_y_dam"]
    assert env.observations.names[:-2] == plain.observations.names
    plain.reset(seed=2)
    env.reset(seed=2)
    _drive(plain, 3)
    obs = _drive(env, 3)[0]
    est = env.estimated_poses
    for i, agent in enumerate(env.agents):
        assert env.observation_space(agent).contains(obs[agent])
        np.testing.assert_array_equal(obs[agent][-2:], (est[i, :2] / 10.0).astype(np.float32))
    # The dict observation puts the block in its vector, before the belief's modes.
    dict_env = coop_loc_env.parallel_env(max_cycles=4, obs_format="dict",
                                         extra_obs_blocks=("est_position",))
    names = dict_env.observations.names
    assert names.index("est_x_dam") == base and names[base + 2].startswith("mode0_")
    dict_obs, _ = dict_env.reset(seed=2)
    assert dict_env.observation_space("robot_0").contains(dict_obs["robot_0"])


class DistanceToCentre(RewardTerm):
    """Minus the weighted true distance to the world's centre."""

    def compute(self, x) -> list[float]:
        centre = np.asarray(self.cfg.world_size) / 2
        d = np.hypot(*(x.env.world.poses[:, :2] - centre).T)
        return [-self.weight * v for v in d.tolist()]


class ErrorChange(RewardTerm):
    """Minus the change of the position error since the last step (a reference kept
    between steps: set at reset, moved on in the advance phase)."""

    def reset(self, x) -> None:
        self.last = x.err_xy.copy()

    def compute(self, x) -> list[float]:
        return (-self.weight * (x.err_xy - self.last)).tolist()

    def advance(self, x) -> None:
        self.last = x.err_xy.copy()


def test_a_registered_reward_term_reaches_the_infos_and_the_reward(registries):
    with pytest.raises(ValueError, match="unknown reward term 'to_centre'"):
        coop_loc_env.make_config("outdoor_terrain", extra_reward_terms=("to_centre",))
    register_reward_term("to_centre", DistanceToCentre, default_weight=0.5)
    register_reward_term("error_change", ErrorChange)
    env = coop_loc_env.parallel_env(max_cycles=6, reward_terms_dict=True,
                                    extra_reward_terms=("to_centre",),
                                    reward_weights={"error_change": 2.0})
    _, infos = env.reset(seed=4)
    first_error = {a: info["position_error"] for a, info in infos.items()}
    change = dict.fromkeys(env.agents, 0.0)
    while env.agents:
        _, rewards, _, _, infos = _drive(env, 1)
        centre = np.asarray(env.config.world_size) / 2
        for agent, info in infos.items():
            terms = info["reward_terms"]
            assert list(terms)[-2:] == ["to_centre", "error_change"]
            assert info["reward_to_centre"] == terms["to_centre"] == pytest.approx(
                -0.5 * np.hypot(*(info["true_pose"][:2] - centre)))
            assert info["reward_error_change"] == terms["error_change"]
            total = 0.0
            for value in terms.values():  # the reward adds the terms left to right
                total += value
            assert rewards[agent] == total
            change[agent] += terms["error_change"]
    for agent, info in infos.items():  # the reference moved on every step: it telescopes
        assert change[agent] == pytest.approx(-2.0 * (info["position_error"]
                                                      - first_error[agent]))
    with pytest.raises(ValueError, match=r"reward_weights\['to_centre'\]"):
        coop_loc_env.make_config("outdoor_terrain", reward_weights={"to_centre": "high"})
    with pytest.raises(ValueError, match="'coverage' is built in"):
        coop_loc_env.make_config("outdoor_terrain", reward_weights={"coverage": 1.0})


class HookedYard(coop_loc_env.Scenario):
    """A small field whose scenario adds an observation block and watches the starts."""

    obs_blocks = ("est_position",)
    starts: list = []

    def base_config(self):
        return coop_loc_env.ScenarioConfig(name="hooked_yard", n_robots=2, max_cycles=3)

    def reset_world(self, env, rng) -> None:
        HookedYard.starts.append(env.world.poses.copy())  # the world is placed already


def test_a_scenario_with_hooks_adds_its_parts_and_runs_at_reset(registries):
    register_obs_block("est_position", EstimatedPosition)
    coop_loc_env.register_scenario("hooked_yard", HookedYard)
    try:
        _check_hooked_yard()
    finally:
        unregister_scenario("hooked_yard")
    assert "hooked_yard" not in coop_loc_env.list_scenarios()


def _check_hooked_yard() -> None:
    assert "small field" in coop_loc_env.describe_scenario("hooked_yard")
    env = coop_loc_env.parallel_env("hooked_yard", n_robots=3)
    assert env.config.n_robots == 3 and env.config.extra_obs_blocks == ("est_position",)
    assert env.observations.names[-1] == "est_y_dam"
    HookedYard.starts.clear()
    for seed in (0, 1):
        _, infos = env.reset(seed=seed)
        assert len(HookedYard.starts) == seed + 1
        np.testing.assert_array_equal(HookedYard.starts[-1][2], infos["robot_2"]["true_pose"])
