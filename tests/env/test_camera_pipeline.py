"""The camera runs when its records are read; what it reports must not depend on when."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
import coop_loc_env.camera as camera_module


def _run(steps: int, read_every_step: bool, seed: int = 4, **overrides):
    """Drive one episode; returns the camera records of the last step and every output."""
    env = coop_loc_env.parallel_env(
        "outdoor_terrain", n_robots=3, max_cycles=10**6, **overrides
    )
    env.reset(seed=seed)
    outputs, seen = [], []
    for _ in range(steps):
        actions = {a: np.array([0.3, 0.05]) for a in env.agents}  # teammates stay in view
        obs, rew, term, trunc, info = env.step(actions)
        outputs.append((obs, rew, info))
        if read_every_step:
            seen.append([env.camera_readings(a) for a in env.possible_agents])
    last = [env.camera_readings(a) for a in env.possible_agents]
    return env, last, outputs, seen


def _same_outputs(a, b) -> None:
    for (obs_a, rew_a, info_a), (obs_b, rew_b, info_b) in zip(a, b, strict=True):
        assert rew_a == rew_b
        for agent in obs_a:
            np.testing.assert_array_equal(obs_a[agent], obs_b[agent])
            assert info_a[agent]["position_error"] == info_b[agent]["position_error"]


def test_records_do_not_depend_on_when_they_are_read():
    _, eager_last, eager_out, eager_seen = _run(40, read_every_step=True)
    env, lazy_last, lazy_out, _ = _run(40, read_every_step=False)
    assert lazy_last == eager_last
    # Tracks refined over 40 frames that nobody read in the lazy run.
    assert max(r.frames for recs in lazy_last for r in recs) == 40
    assert sum(len(recs) for recs in lazy_last) >= 2
    _same_outputs(eager_out, lazy_out)  # reading the camera changes nothing else
    readings = env.last_readings
    assert readings.camera == [[(c.kind, c.id, c.bearing, c.range) for c in recs]
                               for recs in lazy_last]
    # the sightings are the records' pairs, in (observer, target) order, with the true
    # offsets and distances between the robots
    sightings = readings.camera_sightings
    flat = [(i, c) for i, recs in enumerate(lazy_last) for c in recs]
    assert sightings.observer.tolist() == [i for i, _ in flat]
    assert list(sightings.bearing) == [c.bearing for _, c in flat]
    xy = env.world.poses[:, :2]
    robots = [(k, i, c.id) for k, (i, c) in enumerate(flat) if c.kind == "robot"]
    assert robots and all(np.array_equal(sightings.offset[k], xy[j] - xy[i])
                          for k, i, j in robots)
    np.testing.assert_allclose(sightings.dist, np.hypot(*sightings.offset.T), rtol=1e-12)


def test_steps_without_a_frame_read_empty():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=2, camera_rate=5.0)
    env.reset(seed=0)
    framed = []
    for _ in range(6):
        env.step({a: np.array([0.5, 0.0]) for a in env.agents})
        readings = env.last_readings
        framed.append(bool(readings.camera_mask.any()))
        if not framed[-1]:
            assert all(env.camera_readings(a) == [] for a in env.agents)
            assert readings.camera_sightings is None
            assert readings.camera == [[], []]
    assert framed == [False, True] * 3  # a 5 Hz camera at 10 Hz steps


def test_capped_queue_gives_the_same_records(monkeypatch):
    _, want, _, _ = _run(40, read_every_step=False)
    # Room for 7 frames of 3 robots: the older half is processed whenever the queue fills.
    monkeypatch.setattr(camera_module, "MAX_PENDING_BYTES", 7 * 3 * 25)
    env, got, _, _ = _run(40, read_every_step=False)
    assert got == want and any(want)
    assert env.unwrapped.camera._pending == 0 and len(env.unwrapped.camera._poses) == 7


@pytest.mark.parametrize("scenario", ["symmetric_hallway", "hexagon"])
def test_teams_without_cameras_read_nothing(scenario):
    env = coop_loc_env.parallel_env(scenario)
    env.reset(seed=0)
    env.step({a: np.zeros(2) for a in env.agents})
    assert all(env.camera_readings(a) == [] for a in env.agents)
    assert env.last_readings.camera_sightings is None
