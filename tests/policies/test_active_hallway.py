"""The active_hallway scenario and its exploration baseline ``corridor``."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from policies.learning.loader import make_policy
from policies.scripted.corridor import follow
from policies.scripted.view import ScanView


def test_active_hallway_config():
    cfg = coop_loc_env.make_config("active_hallway")
    hall = coop_loc_env.make_config("symmetric_hallway")
    assert (cfg.n_robots, cfg.n_particles, cfg.max_cycles) == (4, 1000, 240)
    assert cfg.estimator == "mcl" and cfg.global_localization
    assert cfg.obstacles == hall.obstacles and cfg.world_size == hall.world_size
    assert coop_loc_env.env_id("active_hallway") == "coop_loc/ActiveHallway-v0"
    defaults = coop_loc_env.scenarios.training_defaults("active_hallway")
    assert defaults["reward_mode"] == "localize"


def _scan(ranges: np.ndarray) -> ScanView:
    angles = np.linspace(-np.pi, np.pi, len(ranges), endpoint=False)
    return ScanView(np.asarray(ranges, dtype=float), angles, 6.0)


def test_follow_steers_toward_the_open_side_and_turns_in_place_when_blocked():
    ranges = np.full(16, 1.25)  # a corridor ...
    ranges[10] = 6.0  # ... with an opening at +45 degrees (beam 10 of 16 from -180)
    forward, turn = follow(_scan(ranges))
    assert forward > 0 and turn > 0.5
    mirrored = np.full(16, 1.25)
    mirrored[6] = 6.0  # the same opening at -45 degrees, on the right
    assert follow(_scan(mirrored))[1] < -0.5
    blocked = np.full(16, 6.0)
    blocked[8] = 0.4  # something right ahead
    forward, turn = follow(_scan(blocked))
    assert forward == 0.0 and abs(turn) == pytest.approx(0.8)


@pytest.mark.parametrize("spec", ["corridor", "wander:1.0"])
def test_exploration_baselines_never_read_the_truth(spec, actions_with_shifted_truth):
    """Shifting the true poses (nothing a robot could know) leaves the actions unchanged."""
    env = coop_loc_env.parallel_env("active_hallway", max_cycles=30)
    policy = make_policy(spec)
    obs, _ = env.reset(seed=2)
    policy.reset(env, seed=2)
    rng = np.random.default_rng(0)
    for _ in range(20):
        before, after = actions_with_shifted_truth(env, policy, obs, rng, shift=3.0)
        assert all(np.array_equal(before[a], after[a]) for a in env.agents)
        obs, *_ = env.step(policy.act(obs))


def test_corridor_speed_is_checked():
    with pytest.raises(ValueError, match="corridor:2"):
        make_policy("corridor:2")
    with pytest.raises(ValueError, match="gain"):
        from policies.scripted import CorridorPolicy

        CorridorPolicy(gain=0.0)


def test_active_hallway_starts_4000_particles_a_robot():
    """Global localization over the hallway starts each robot's filter with 4 times the
    scenario's 1000 particles, spread over the whole free space."""
    env = coop_loc_env.parallel_env("active_hallway", max_cycles=2)
    _, infos = env.reset(seed=0)
    assert [i["n_particles"] for i in infos.values()] == [4000] * 4
    assert all(i["particle_spread"] > 5.0 for i in infos.values())
