"""Observations are built from what the robots sensed, never from the true poses.

Two copies of an env run with the same seed and actions. In the second, the true
poses are moved every step right after the sensors (camera included) have read
them, so everything downstream (estimators, the team map, the observation
builder) sees a wrong truth. ``World.step`` overwrites the poses from the
physics bodies, so the motion of both copies stays the same; the observations
must be equal. Two cheating controls show the check can fail: the privileged
observation (which appends the true pose) and an estimator that peeks at it.
"""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.scenarios import make_config

SCENARIOS = coop_loc_env.list_scenarios()
ESTIMATORS = ("ekf", "mcl", "mle")
STEPS = 12
# Particle counts and teams cut so the 24 cases run in seconds; no tip-over ends an
# episode (the moved copy's tip-over check reads the moved poses).
SMALL = {"n_particles": 150, "tip_over_terminates": False}
MAX_TEAM = 4


def _small(scenario: str) -> dict:
    cfg = make_config(scenario)
    if cfg.start_poses is None and cfg.n_robots > MAX_TEAM:
        return {**SMALL, "n_robots": MAX_TEAM}
    return dict(SMALL)


def _perturb_after_sensing(env, rng: np.random.Generator, shift: float = 3.0) -> list[str]:
    """Move ``env``'s true poses after each step's sensing (camera frame queued).

    Returns the list the env's calls are logged to (``moved``, then ``estimate`` per
    backend and ``map``), so a caller can check the poses moved before they were used.
    """
    calls: list[str] = []
    add_step = env.camera.add_step

    def add_then_move(poses, mask):
        add_step(poses, mask)
        n = len(env.world.poses)
        env.world.poses[:, :2] += rng.uniform(-shift, shift, size=(n, 2))
        env.world.poses[:, 2] += rng.uniform(-1.0, 1.0, size=n)
        calls.append("moved")

    def logged(name, method):
        def call(*args, **kwargs):
            calls.append(name)
            return method(*args, **kwargs)

        return call

    env.camera.add_step = add_then_move
    for backend in env.backends:
        backend.step = logged("estimate", backend.step)
    env.mapper.step = logged("map", env.mapper.step)
    return calls


def _observations_differ(scenario: str, seed: int = 0, cheat=None, **overrides) -> list[int]:
    """Steps at which the two copies' observations differ (0 = after reset)."""
    kwargs = {**_small(scenario), **overrides}
    honest = coop_loc_env.parallel_env(scenario, **kwargs)
    moved = coop_loc_env.parallel_env(scenario, **kwargs)
    obs_a, _ = honest.reset(seed=seed)
    obs_b, _ = moved.reset(seed=seed)
    calls = _perturb_after_sensing(moved, np.random.default_rng(seed + 100))
    if cheat is not None:
        cheat(moved)
    actions_rng = np.random.default_rng(seed)
    differ = [0] if any(not np.array_equal(obs_a[a], obs_b[a]) for a in obs_a) else []
    for t in range(1, STEPS + 1):
        draw = actions_rng.uniform(-1, 1, size=(len(honest.possible_agents), 2))
        actions = {a: draw[i].astype(np.float32) for i, a in enumerate(honest.agents)}
        obs_a, *_ = honest.step(actions)
        obs_b, *_ = moved.step(actions)
        # the truth moved before the estimators and the map used anything of this step
        assert calls == ["moved"] + ["estimate"] * len(moved.backends) + ["map"], calls
        calls.clear()
        # the physics, hence the next step's sensing, is the same in both copies
        np.testing.assert_array_equal(honest.world.poses[:, :2], _true_poses(moved)[:, :2])
        assert obs_a.keys() == obs_b.keys()
        if any(not np.array_equal(obs_a[a], obs_b[a]) for a in obs_a):
            differ.append(t)
    return differ


def _true_poses(env) -> np.ndarray:
    """The physics bodies' positions (the moved copy's ``world.poses`` are wrong)."""
    bodies = env.world.bodies
    return np.array([[b.position.x, b.position.y, b.angle] for b in bodies])


@pytest.mark.parametrize("estimator", ESTIMATORS)
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_observation_never_reads_the_true_poses(scenario, estimator):
    assert _observations_differ(scenario, estimator=estimator) == []


@pytest.mark.parametrize("estimator", ESTIMATORS)
def test_map_patch_and_teammate_blocks_never_read_the_true_poses(estimator):
    differ = _observations_differ("outdoor_terrain", estimator=estimator, map_patch_obs=5,
                                  teammate_obs=True)
    assert differ == []


def test_privileged_observation_is_caught():
    differ = _observations_differ("outdoor_terrain", privileged_obs=True)
    assert differ == list(range(1, STEPS + 1))


def test_estimator_that_peeks_at_the_truth_is_caught():
    def cheat(env):
        backend = env.backends[0]
        step = backend.step

        def peeking_step(readings, active):
            out = step(readings, active)
            backend.ekf.mean[:, :2] = env.world.poses[backend.robots, :2]
            return out

        backend.step = peeking_step

    differ = _observations_differ("outdoor_terrain", estimator="ekf", cheat=cheat)
    assert differ == list(range(1, STEPS + 1))
