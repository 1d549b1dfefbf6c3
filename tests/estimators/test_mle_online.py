"""Tests of the online sliding-window team MLE (TeamMLE) and odometry integration."""

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.geometry import relative_pose, wrap_angle
from estimators.mle_online import (
    OdometryIntegrator,
    TeamMLE,
    TeamStream,
    feed_stream,
    integrate_odometry,
    simulate_team_stream,
)
from estimators.pose_graph import PairSensing, compose
from estimators.relative_metrics import relative_errors


def _pairs(p_observe: float) -> PairSensing:
    """Pairs within 6 m observed with probability ``p_observe`` per step."""
    return PairSensing(sensor_range=6.0, p_observe=p_observe)


@pytest.fixture(scope="module")
def stream() -> TeamStream:
    return simulate_team_stream(6, 600, np.random.default_rng(0), sensing=_pairs(0.05))


def _run(stream: TeamStream, components: str = "rbo", drop_obs: bool = False, **kwargs) -> TeamMLE:
    kwargs.setdefault("initial_poses", stream.truth[0])
    kwargs.setdefault("initial_std", [0.3, 0.3, 0.1])
    kwargs.setdefault("motion_window", 3.0)
    est = TeamMLE(stream.truth.shape[1], **kwargs)
    if drop_obs:
        stream = TeamStream(stream.dt, stream.truth, stream.odometry,
                            [[] for _ in stream.observations])
    for _ in feed_stream(est, stream, components=components):
        pass
    return est


def test_integrator_matches_arc_and_grows_covariance():
    v, w, n, dt = 0.5, 0.2, 1000, 0.01  # 10 s on an arc of radius 2.5 m
    delta, cov = integrate_odometry(np.full(n, v), np.full(n, w), dt, 0.05, 0.02)
    th = w * n * dt
    expected = [v / w * np.sin(th), v / w * (1 - np.cos(th)), th]
    np.testing.assert_allclose(delta, expected, atol=5e-3)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert cov[2, 2] == pytest.approx(n * (dt * 0.02) ** 2)
    acc = OdometryIntegrator.zero()
    acc.add(1.0, 0.0, 1.0, 0.1, 0.0)
    np.testing.assert_allclose(acc.delta, [1.0, 0.0, 0.0])
    assert acc.cov[0, 0] == pytest.approx(0.01) and acc.cov[1, 1] == 0.0


def test_sliding_window_stays_close_to_full_batch(stream):
    windowed = _run(stream, window=3, keep_history=True)
    batch = _run(stream, window=None)
    assert windowed.n_active_nodes < 0.3 * batch.n_active_nodes
    truth = stream.truth[-1]
    err_w = relative_errors(windowed.poses(), truth)
    err_b = relative_errors(batch.poses(), truth)
    gap = np.abs(windowed.poses() - batch.poses())
    gap[:, 2] = wrap_angle(gap[:, 2])
    assert gap[:, :2].max() < 0.05 and np.abs(gap[:, 2]).max() < 0.01
    np.testing.assert_allclose(err_w, err_b, rtol=0.1, atol=0.01)
    # the offline re-solve of the recorded history agrees with the online full batch
    np.testing.assert_allclose(windowed.solve_batch(), batch.poses(), atol=1e-4)
    # marginal covariances of the window are close to those of the full graph
    np.testing.assert_allclose(windowed.covariances(), batch.covariances(), rtol=0.2, atol=1e-4)


def test_window_bounds_graph_size_on_long_runs():
    stream = simulate_team_stream(4, 900, np.random.default_rng(1), sensing=_pairs(0.1))
    est = TeamMLE(4, initial_poses=stream.truth[0], motion_window=2.0, window=3)
    sizes = []
    for k in feed_stream(est, stream):
        if k % 50 == 49:
            sizes.append((est.n_active_nodes, est.graph.n_observations, est.graph.n_between))
    sizes = np.array(sizes)
    assert sizes[:, 0].max() <= 4 * 4  # window + the newest keyframe per robot
    assert sizes[-1, 2] <= 4 * 4
    assert sizes[3:, 1].max() <= 1.5 * sizes[3:, 1].mean() + 10  # no growth with time
    assert est.graph.n_nodes > 4 * 20  # many keyframes were created and dropped


@pytest.mark.parametrize("components", ["rbo", "rb"])
def test_observations_beat_odometry_alone(stream, components):
    """Start poses known only roughly: sightings of teammates fix the relative poses."""
    rng = np.random.default_rng(9)
    start = stream.truth[0] + rng.normal(0.0, [0.5, 0.5, 0.3], (6, 3))
    start[0] = stream.truth[0, 0]  # the anchor
    kw = {"initial_poses": start, "initial_std": [0.5, 0.5, 0.3], "window": 4}
    truth = stream.truth[-1]
    err_odo = relative_errors(_run(stream, drop_obs=True, **kw).poses(), truth)
    est = _run(stream, components=components, **kw)
    err = relative_errors(est.poses(), truth)
    assert err[0] < 0.3 * err_odo[0]
    assert err[1] < 0.5 * err_odo[1]
    assert err[2] < 0.5 * err_odo[2]
    assert np.all(np.isfinite(est.covariances()))
    rel = est.relative_poses()
    assert rel.shape == (6, 6, 3)
    np.testing.assert_array_equal(rel[[0, 1], [0, 1]], 0.0)


def test_covariance_is_consistent_with_errors():
    """Mean NEES of the latest poses of robots 1-4 over seeds 0-3 (16 samples), within its
    two-sided 99.9 % band.

    The four robots of one run share the anchor and their sightings: their NEES correlate
    (0.44 on average), so a run's mean of 4 counts as 4.9 chi-square dof, not 12 (measured
    over seeds 4-67: mean NEES 3.00 over 256 samples, 4.7 % above the 95 % quantile; the
    variance of a run's mean, 3.69, gives the dof). Four runs: chi2(19.5) * 3 / 19.5, from
    0.79 to 7.19. Seeds 0-3 give 5.77, in its upper 1 % (robot 1 reads 6.9-9.4 in all four
    runs; five samples of 16 make half the sum): a rare case, not an overconfident filter.
    """
    nees = []
    for seed in range(4):
        stream = simulate_team_stream(5, 300, np.random.default_rng(seed), sensing=_pairs(0.1))
        est = _run(stream, window=5)
        err = est.poses() - stream.truth[-1]
        err[:, 2] = wrap_angle(err[:, 2])
        cov = est.covariances()
        nees.extend(np.einsum("ki,kij,kj->k", err[1:], np.linalg.inv(cov[1:]), err[1:]))
    dof = 4 * 4.88
    lo, hi = chi2.ppf(0.0005, dof) * 3 / dof, chi2.ppf(0.9995, dof) * 3 / dof
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)


def test_stationary_robots_and_zero_range_give_no_nan():
    est = TeamMLE(3, initial_poses=np.zeros((3, 3)), motion_window=1.0, window=2)
    for k in range(60):
        est.add_odometry(0, 0.0, 0.0, 0.1)  # never moves
        est.add_odometry(1, 0.0, 0.0, 0.1)  # never moves, on top of robot 0
        est.add_odometry(2, 0.3, 0.1, 0.1)
        if k % 10 == 0:
            assert est.add_observation(0, 1, [0.0, 0.3, 0.0], [0.05, 0.05, 0.05])
            est.add_observation(2, 0, [1.0, 0.0], [0.1, 0.05], components="rb")
        est.step()
        assert np.all(np.isfinite(est.poses()))
    cov = est.covariances()
    assert np.all(np.isfinite(cov)) and np.all(np.linalg.eigvalsh(cov[1:]) > 0)
    np.testing.assert_allclose(est.poses()[0], 0.0, atol=0.05)  # anchored, did not move
    np.testing.assert_allclose(est.poses()[1, :2], 0.0, atol=0.05)


def test_motion_floor_is_the_variance_of_a_still_robot():
    """A robot that stands still with exact odometry gains only the motion floor per
    motion factor: after 5 s of 1 s keyframes its covariance is its prior, 1e-3 std,
    plus 5 floors of 1e-3 m (rad) std each."""
    est = TeamMLE(2, initial_poses=np.zeros((2, 3)), initial_std=[1e-3, 1e-3, 1e-3],
                  motion_window=1.0, window=None)
    for _ in range(50):
        for robot in (0, 1):
            est.add_odometry(robot, 0.0, 0.0, 0.1, std=(0.0, 0.0))
        est.step()
    assert est.graph.n_between == 2 * 5
    np.testing.assert_allclose(est.covariances()[1], np.eye(3) * (1e-6 + 5 * 1e-6), rtol=1e-6,
                               atol=1e-12)


def test_full_covariance_observation_equals_diagonal_std():
    runs = []
    for use_cov in (False, True):
        est = TeamMLE(2, initial_poses=[[0.0, 0.0, 0.0], [2.0, 0.5, 0.3]],
                      initial_std=[1.0, 1.0, 0.5])
        std = np.array([0.1, 0.05])
        if use_cov:
            assert est.add_observation(0, 1, [2.0, 0.2], cov=np.diag(std**2), components="rb")
        else:
            assert est.add_observation(0, 1, [2.0, 0.2], std, components="rb")
        est.step()
        runs.append((est.poses(), est.covariances()))
    np.testing.assert_allclose(runs[0][0], runs[1][0])
    np.testing.assert_allclose(runs[0][1], runs[1][1])
    assert not np.allclose(runs[0][0][1], [2.0, 0.5, 0.3])  # the observation moved robot 1


def test_inputs_are_not_modified_and_headings_wrapped():
    start = np.array([[0.0, 0.0, 4.0], [1.0, 0.0, -4.0]])
    copy = start.copy()
    est = TeamMLE(2, initial_poses=start)
    np.testing.assert_array_equal(start, copy)
    np.testing.assert_allclose(est.poses()[:, 2], wrap_angle(copy[:, 2]))


def test_observation_rate_limit_and_keyframes():
    est = TeamMLE(2, observation_interval=1.0, keyframe_interval=0.5, motion_window=10.0)
    est.add_odometry(0, 0.1, 0.0, 0.1)
    assert est.add_observation(0, 1, [1.0, 0.0, 0.0], [0.1, 0.1, 0.1])
    assert not est.add_observation(0, 1, [1.0, 0.0, 0.0], [0.1, 0.1, 0.1])
    assert est.add_observation(1, 0, [1.0, np.pi, 0.0], [0.1, 0.1, 0.1])  # other direction
    assert est.graph.n_nodes == 2  # 0.1 s < keyframe_interval: attached with offsets
    for _ in range(10):
        est.add_odometry(0, 0.1, 0.0, 0.1)
    assert est.add_observation(0, 1, [1.0, 0.0, 0.0], [0.1, 0.1, 0.1])
    assert est.graph.n_nodes == 3  # robot 0 got a keyframe at the observation
    res = est.step()
    # 2 free nodes (robot 0's second keyframe, robot 1); residuals: 3 sightings of 3
    # components, robot 1's prior and robot 0's motion factor, 3 each
    assert res.converged and (res.n_variables, res.n_residuals) == (6, 15)
    # robot 1 lies between where its sightings put it: 1.01 m (t = 0.1 s) and 1.11 m
    assert 1.01 <= est.poses()[1, 0] <= 1.11
    assert est.step() is None  # nothing new


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda e: e.add_odometry(3, 0.1, 0.0, 0.1),
         r'robot index in \[0, 2\), got 3'),
        (lambda e: e.add_odometry(0, np.nan, 0.0, 0.1),
         r'got \(nan, 0.0, 0.1\)'),
        (lambda e: e.add_odometry(0, 0.1, 0.0, -0.1),
         r'dt >= 0, got \(0.1, 0.0, -0.1\)'),
        (lambda e: e.add_observation(0, 0, [1.0, 0.0, 0.0], [0.1, 0.1, 0.1]),
         'observer = target = 0'),
        (lambda e: e.add_observation(0, 1, [1.0, 0.0], [0.1, 0.1, 0.1]),
         r'3 finite numbers, got \[1.0, 0.0\]'),
        (lambda e: e.add_observation(0, 1, [1.0, 0.0], [0.1, 0.1], components="rz"),
         "subset of 'rbo', got 'rz'"),
        (lambda e: e.add_observation(0, 1, [1.0, 0.0], [0.1, -0.1], components="rb"),
         r'2 positive numbers, got \[0.1, -0.1\]'),
        (lambda e: e.solve_batch(),
         'keep_history=True'),
        (lambda e: e.add_observation(0, 1, [1.0], std=[0.1], cov=[[0.01]], components="r"),
         'exactly one of std and cov'),
        (lambda e: e.add_observation(0, 1, [1.0, 0.0], cov=[[0.01, 0.0], [0.0, -1.0]],
                                     components="rb"),
         r'(?s)positive definite.*-1\.'),
    ],
)
def test_bad_input_raises_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call(TeamMLE(2))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_robots": 0},
         'n_robots must be >= 1, got 0'),
        ({"n_robots": 2, "anchor": 5},
         r'anchor must be a robot index in \[0, 2\), got 5'),
        ({"n_robots": 2, "window": 0},
         'window must be >= 1 or None, got 0'),
        ({"n_robots": 2, "initial_poses": np.zeros((3, 3))},
         r'initial_poses must be finite with shape \(2, 3\)'),
        ({"n_robots": 2, "initial_std": [0.1, 0.0, 0.1]},
         'initial_std row 1 mixes zero and non-zero'),
        ({"n_robots": 2, "odometry_std": (0.1, -1.0)},
         r'odometry_std .*got \(0.1, -1.0\)'),
        ({"n_robots": 2, "motion_window": 0.0},
         'motion_window must be > 0, got 0.0'),
        ({"n_robots": 2, "gate_prob": 1.5},
         r'gate_prob must be in \(0, 1\) or None, got 1.5'),
    ],
)
def test_bad_config_raises_value_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TeamMLE(**kwargs)


def test_solve_interval_defers_optimization_until_due():
    est = TeamMLE(2, solve_interval=1.0, motion_window=5.0, observation_interval=0.0)
    first = est.step()  # initial keyframes: robot 1's prior, nothing to fit yet
    assert (first.n_variables, first.n_residuals, first.cost) == (3, 3, 0.0)
    solved = []
    for _ in range(20):
        est.add_odometry(0, 0.1, 0.0, 0.1)
        est.add_odometry(1, 0.1, 0.0, 0.1)
        est.add_observation(0, 1, [1.0, 0.0, 0.0], [0.1, 0.1, 0.1])
        solved.append(est.step() is not None)
    # solves only when 1 s has passed (t = 1 s and 2 s, also keyframe times here)
    assert solved == [k in (9, 19) for k in range(20)]
    assert est.graph.n_observations == 20  # waiting observations were all kept


def test_offset_covariance_matches_numeric_propagation():
    """Observations attached through odometry offsets get the offsets' covariance."""
    est = TeamMLE(2, initial_poses=[[0.0, 0.0, 0.3], [3.0, 1.0, -1.0]], keyframe_interval=None)
    for _ in range(5):
        est.add_odometry(0, 0.4, 0.2, 0.1, std=(0.1, 0.1))
        est.add_odometry(1, 0.3, -0.3, 0.1, std=(0.2, 0.05))
    ka, kb = est.graph.poses[0], est.graph.poses[1]
    oa, ob = est._odom[0], est._odom[1]

    def g(da, db):
        return relative_pose(compose(ka, oa.delta + da), compose(kb, ob.delta + db))

    h = 1e-6
    ja = np.stack([(g(h * e, 0) - g(-h * e, 0)) / (2 * h) for e in np.eye(3)], axis=1)
    jb = np.stack([(g(0, h * e) - g(0, -h * e)) / (2 * h) for e in np.eye(3)], axis=1)
    expected = ja @ oa.cov @ ja.T + jb @ ob.cov @ jb.T
    np.testing.assert_allclose(est._offset_covariance(0, 1, "rbo"), expected, rtol=1e-5,
                               atol=1e-12)
    np.testing.assert_allclose(est._offset_covariance(0, 1, "rb"), expected[:2, :2], rtol=1e-5,
                               atol=1e-12)


def test_gate_rejects_false_detections():
    stream = simulate_team_stream(5, 300, np.random.default_rng(4), sensing=_pairs(0.1))
    rng = np.random.default_rng(5)
    fakes = {}
    for k in range(10, 300, 10):  # a random sighting of a random teammate every second
        a, b = rng.choice(5, 2, replace=False)
        z = [rng.uniform(0.5, 6.0), rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi)]
        fakes[k] = (int(a), int(b), np.array(z))
    errors, accepted_fakes, gated = {}, {}, {}
    for gate in (None, 0.999, "clean"):  # "clean": no gate, no false detections
        est = TeamMLE(5, initial_poses=stream.truth[0], initial_std=[0.3, 0.3, 0.1],
                      motion_window=3.0, window=5, gate_prob=None if gate == "clean" else gate,
                      observation_interval=0.0)
        accepted_fakes[gate] = 0
        for k in range(300):
            for r in range(5):
                est.add_odometry(r, *stream.odometry[k, r], stream.dt)
            for a, b, meas, std in stream.observations[k]:
                est.add_observation(a, b, meas, std)
            if k in fakes and gate != "clean":
                a, b, z = fakes[k]
                accepted_fakes[gate] += est.add_observation(a, b, z, [0.1, 0.03, 0.03])
            est.step()
        errors[gate] = relative_errors(est.poses(), stream.truth[-1])
        gated[gate] = est.n_gated
    assert accepted_fakes[None] == len(fakes) and gated[None] == 0
    # the gate rejects every false detection and no genuine sighting, so the gated run
    # solves the same graph as the clean one (errors 0.103 m, 0.042, 0.045 rad; without
    # the gate the range error is 9.05 m)
    assert accepted_fakes[0.999] == 0 and gated[0.999] == len(fakes)
    np.testing.assert_allclose(errors[0.999], errors["clean"], rtol=1e-9, atol=1e-12)
    assert errors[None][0] > 10 * errors["clean"][0]


def test_priors_alone_fix_the_frame_without_anchor(stream):
    est = _run(stream, anchor=None, window=4)
    assert not est.graph.fixed.any()
    cov = est.covariances()
    assert np.all(np.linalg.eigvalsh(cov) > 0)  # the anchor robot has a covariance too
    assert relative_errors(est.poses(), stream.truth[-1])[0] < 0.3
