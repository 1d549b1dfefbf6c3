"""PettingZoo's own API, seed, render and max-cycles tests on every registered scenario."""

from __future__ import annotations

import functools
import pickle
import sys
import types

import numpy as np
import pettingzoo
import pytest
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
    seed_test,
)

import coop_loc_env

SCENARIOS = coop_loc_env.list_scenarios()
# Keep the suite fast: short episodes and, for particle filters, fewer particles.
FAST = {"max_cycles": 25, "n_particles": 200}


def _make_parallel(scenario, **kw):
    return coop_loc_env.parallel_env(scenario, **{**FAST, **kw})


def _make_aec(scenario, **kw):
    return coop_loc_env.env(scenario, **{**FAST, **kw})


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_parallel_api(scenario):
    parallel_api_test(_make_parallel(scenario), num_cycles=25)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_parallel_seed(scenario):
    parallel_seed_test(functools.partial(_make_parallel, scenario), num_cycles=25)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_aec_api(scenario):
    api_test(_make_aec(scenario), num_cycles=25)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_aec_seed(scenario):
    seed_test(functools.partial(_make_aec, scenario), num_cycles=25)


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_render(scenario):
    render_test(functools.partial(_make_aec, scenario, max_cycles=6))


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_max_cycles(scenario):
    mod = types.SimpleNamespace(
        parallel_env=functools.partial(coop_loc_env.parallel_env, scenario, n_particles=200),
        env=functools.partial(coop_loc_env.env, scenario, n_particles=200),
    )
    max_cycles_test(mod)


def test_pettingzoo_registry_makes_every_scenario():
    for scenario in SCENARIOS:
        env = pettingzoo.make("parallel", coop_loc_env.env_id(scenario), max_cycles=5)
        assert isinstance(env, coop_loc_env.CoopLocParallelEnv)
        assert env.config.name == scenario
        assert env.config.max_cycles == 5
    aec = pettingzoo.make("aec", "coop_loc/OutdoorTerrain-v0")
    aec.reset(seed=0)
    assert aec.agents == aec.possible_agents


def test_spaces_are_the_same_object_and_metadata():
    env = coop_loc_env.parallel_env(max_cycles=5)
    for agent in env.possible_agents:
        assert env.observation_space(agent) is env.observation_space(agent)
        assert env.action_space(agent) is env.action_space(agent)
    for key in ("name", "render_modes", "render_fps", "is_parallelizable"):
        assert key in env.metadata
    assert env.metadata["is_parallelizable"] is True


def test_env_is_picklable_mid_episode():
    env = coop_loc_env.parallel_env(max_cycles=20, n_robots=2)
    env.reset(seed=3)
    actions = {a: np.array([0.5, 0.1], dtype=np.float32) for a in env.agents}
    for _ in range(3):
        env.step(actions)
    clone = pickle.loads(pickle.dumps(env))
    out_a = env.step(actions)
    out_b = clone.step(actions)
    for agent in env.possible_agents:
        np.testing.assert_array_equal(out_a[0][agent], out_b[0][agent])
        assert out_a[1][agent] == out_b[1][agent]


def test_list_scenarios_includes_outdoor_terrain():
    assert "outdoor_terrain" in SCENARIOS
    assert SCENARIOS == sorted(SCENARIOS)


def test_module_exposes_pettingzoo_style_constructors():
    mod = sys.modules["coop_loc_env"]
    for name in ("parallel_env", "env", "raw_env"):
        assert callable(getattr(mod, name))
    raw = coop_loc_env.raw_env(max_cycles=3)
    raw.reset(seed=0)
    assert raw.agents == ["robot_0", "robot_1", "robot_2"]
