"""The terrain-traversal state machine in a constructed scene, and the baselines."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env import Obstacle
from policies.scripted.baselines import RandomPolicy, SeekTeammatePolicy
from policies.scripted.fsm import FSMParams, FSMPolicy, State

# layout_seed 6 puts the single steep mound of this flat 30 m world here:
MOUND = np.array([15.801451380910807, 11.708688266080106])
TIP_RADIUS = 1.86  # the mound's slope exceeds 30 deg inside this radius


def _scene(objects, start, max_cycles, **kw):
    env = coop_loc_env.parallel_env(
        n_robots=1,
        world_size=(30.0, 30.0),
        layout_seed=6,
        n_random_trees=0,
        n_random_rocks=0,
        n_random_ooi=0,
        terrain_amplitude=0.0,
        terrain_hills=0,
        steep_patches=1,
        obstacles=tuple(
            Obstacle("ooi", "circle", center=tuple(MOUND + off), radius=0.3) for off in objects
        ),
        start_poses=(start,),
        max_cycles=max_cycles,
        **kw,
    )
    assert np.allclose(env.world.terrain.steep_centers[0], MOUND)
    return env


def _run(env, policy, seed=0):
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed=seed)
    trace = []
    while env.agents:
        obs, _, _, _, infos = env.step(policy.act(obs))
        info = infos["robot_0"]
        trace.append((policy.states()["robot_0"], info["true_pose"].copy(), info["collisions"],
                      info["tipped_over"]))
    return trace


def test_fsm_long_run_visits_every_state_safely():
    # Object B is seen first (closest); the way from B to object A crosses the mound.
    start = (MOUND[0] - 6.0, MOUND[1] - 6.0, np.pi / 2)
    env = _scene([(3.5, 0.0), (-6.0, 0.0)], start, max_cycles=900)
    policy = FSMPolicy()
    trace = _run(env, policy)
    states = {s for s, *_ in trace}
    assert states == {s.value for s in State}
    fsm = policy.machines["robot_0"]
    assert set(fsm.history) == set(State)
    poses = np.array([p for _, p, _, _ in trace])
    assert sum(c for _, _, c, _ in trace) == 0  # never touched an obstacle
    assert not any(t for *_, t in trace)
    assert not env.world.terrain.is_steep(poses[:, :2]).any()
    assert np.hypot(*(poses[:, :2] - MOUND).T).min() > TIP_RADIUS
    # Object B was reached and marked on the team map near its true position.
    assert len(fsm.visited) >= 1 and env.terrain_map.objects
    marked = np.array(env.terrain_map.objects)[:, :2]
    assert np.hypot(*(marked - (MOUND + (-6.0, 0.0))).T).min() < 1.0
    # Elevation was recorded along the way (one sample per 1 Hz inclinometer reading).
    assert len(fsm.elevation_log) >= 80


def test_boundary_triggers_near_steep_terrain():
    start = (MOUND[0] - 6.0, MOUND[1] + 0.3, 0.0)
    env = _scene([(4.0, 0.0)], start, max_cycles=400)
    policy = FSMPolicy()
    trace = _run(env, policy)
    states = [s for s, *_ in trace]
    assert "Boundary" in states
    k = states.index("Boundary")
    d = np.hypot(*(trace[k][1][:2] - MOUND))
    assert TIP_RADIUS < d < 3.0  # triggered on the mound's flank, before the tip-over ring
    poses = np.array([p for _, p, _, _ in trace])
    assert not env.world.terrain.is_steep(poses[:, :2]).any()
    fsm = policy.machines["robot_0"]
    assert fsm.hazards and np.hypot(*(fsm.hazards[0] - MOUND)) < 2.5
    # After backing off it does not drive back into the mound.
    assert np.hypot(*(poses[k + 40 :, :2] - MOUND).T).min() > d - 0.3


def test_fsm_view_holds_the_belief_not_the_truth():
    env = _scene([(3.5, 0.0)], (5.0, 5.0, 0.0), max_cycles=5)
    obs, _ = env.reset(seed=0)
    policy = FSMPolicy()
    policy.reset(env, seed=0)
    view = policy._views.view("robot_0", obs["robot_0"])
    assert np.allclose(view.est_pose, env.estimated_poses[0])
    assert not np.allclose(view.est_pose, env.world.poses[0])  # belief, not truth


def test_fsm_params_validated():
    with pytest.raises(ValueError, match="boundary_slope_deg"):
        FSMPolicy(FSMParams(boundary_slope_deg=5.0, slow_slope_deg=9.0))
    with pytest.raises(ValueError, match="cruise_speed"):
        FSMPolicy(FSMParams(cruise_speed=1.5))


def test_seek_policy_drives_uncertain_robot_toward_teammate():
    env = coop_loc_env.parallel_env(
        n_robots=2, max_cycles=150, n_random_trees=0, n_random_rocks=0, steep_patches=0,
        terrain_amplitude=0.0, start_poses=((8.0, 8.0, 0.0), (20.0, 8.0, np.pi / 2)),
        team=(coop_loc_env.RobotSpec(has_gps=False), coop_loc_env.RobotSpec()),
        detector_range=4.0,
    )
    policy = SeekTeammatePolicy(std_threshold=0.3)
    obs, _ = env.reset(seed=0)
    policy.reset(env, seed=0)
    d0 = np.hypot(*(env.world.poses[0, :2] - env.world.poses[1, :2]))
    for _ in range(150):
        if not env.agents:
            break
        obs, *_ = env.step(policy.act(obs))
    d1 = np.hypot(*(env.world.poses[0, :2] - env.world.poses[1, :2]))
    assert d1 < 0.5 * d0
    with pytest.raises(ValueError, match="std_threshold"):
        SeekTeammatePolicy(std_threshold=0.0)


def test_random_policy_is_seeded():
    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    a, b = RandomPolicy(), RandomPolicy()
    a.reset(env, seed=3)
    b.reset(env, seed=3)
    x, y = a.act(obs), b.act(obs)
    assert all(np.array_equal(x[k], y[k]) for k in x)
    assert all(np.all(np.abs(v) <= 1) for v in x.values())


def _view(heading=0.0, camera=(), front=15.0, team_objects=(), pitch=0.0, incl_new=False):
    from coop_loc_env.depth_from_motion import CameraRecord
    from policies.scripted.view import RobotView

    lo = np.linspace(-np.pi / 2, np.pi / 2, 17)[:-1]
    hi = lo + np.pi / 16
    ranges = np.full(16, 15.0)
    ranges[7:9] = front
    return RobotView(
        index=0, est_pose=np.array([5.0, 5.0, heading]), pose_cov=np.eye(3) * 0.01,
        pitch=pitch, roll=0.0, incl_new=incl_new, ranges=ranges, bin_lo=lo, bin_hi=hi,
        max_range=15.0, camera=[CameraRecord("ooi", 0, *c) for c in camera],
        camera_frame=True, teammates=np.zeros((1, 3)),
        team_objects=np.array(team_objects, dtype=float).reshape(-1, 2),
        world_size=(30.0, 30.0), dt=0.1,
    )


def _full_scan(fsm, **kw):
    heading = 0.0
    for _ in range(200):
        a = fsm.act(_view(heading=heading, camera=[(0.0, 4.0, 1.0, 1)], **kw))
        heading = float(np.angle(np.exp(1j * (heading + a[1] * 0.1))))
        if fsm.state != State.SCAN:
            return


def test_scan_locks_on_unless_a_teammate_marked_the_object():
    from policies.scripted.fsm import TraversalFSM

    fsm = TraversalFSM()
    _full_scan(fsm)
    assert fsm.state == State.LOCK_ON and fsm.target == 0
    fsm = TraversalFSM()
    _full_scan(fsm, team_objects=[(9.2, 5.1)])  # object 0 lies at (9, 5)
    assert fsm.state == State.ELEV_GRADIENT and fsm.target is None and fsm.waypoint is not None


def test_obstacle_ahead_interrupts_driving_and_steep_reading_wins():
    from policies.scripted.fsm import TraversalFSM

    fsm = TraversalFSM()
    fsm.state, fsm.waypoint = State.ELEV_GRADIENT, np.array([20.0, 5.0])
    a = fsm.act(_view(front=0.8))
    assert fsm.state == State.OBJECT_AVOID and a[0] == 0.0 and abs(a[1]) > 0
    a = fsm.act(_view(front=0.8, pitch=np.deg2rad(20.0), incl_new=True))
    assert fsm.state == State.BOUNDARY and a[0] < 0  # uphill ahead: reverse
    assert len(fsm.hazards) == 1 and fsm.hazards[0][0] > 5.0  # hazard placed uphill (ahead)
