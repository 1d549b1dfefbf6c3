"""Our pose-graph solver against GTSAM on the graph of the Howard circuit reproduction."""

from __future__ import annotations

import gtsam  # noqa: F401  (the dev extra installs it: this check always runs)
import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.backends.mle import MLEBackend
from coop_loc_env.profiles import with_profile
from estimators.geometry import wrap_angle
from estimators.gtsam_bridge import dead_reckoning, gtsam_solve, to_gtsam
from estimators.pose_graph import PoseGraph, optimize
from policies.scripted.circuit import CircuitPolicy


def _circuit_graph(seconds: float) -> PoseGraph:
    """The whole graph the paper profile solves (anchor prior, free robots, sightings)."""
    env = coop_loc_env.parallel_env("circuit", **with_profile("circuit", "paper"))
    obs, _ = env.reset(seed=0)
    policy = CircuitPolicy()
    policy.reset(env, 0)
    for _ in range(int(round(seconds / env.config.dt))):
        obs, *_ = env.step(policy.act(obs))
    return next(b for b in env.backends if isinstance(b, MLEBackend)).mle.graph


def test_batch_solve_matches_gtsam_on_the_circuit_graph():
    graph = _circuit_graph(25.0)  # the driver has seen robots 0 and 1
    assert graph.n_observations > 10 and len(graph.priors) == 7
    start = dead_reckoning(graph)
    fg, _ = to_gtsam(graph, start)
    assert fg.error(gtsam_values(start, graph)) == pytest.approx(graph.cost(start), rel=1e-9)
    graph.poses[:] = start
    ours = optimize(graph, max_iterations=100)
    theirs = gtsam_solve(graph, start)
    assert ours.converged and ours.cost < 0.9 * graph.cost(start)
    assert abs(ours.cost - theirs.cost) <= 1e-6 * theirs.cost
    # The free robots' 1 km priors leave directions where the cost is flat to ~1e-12:
    # the two optima agree to millimetres there.
    np.testing.assert_allclose(graph.poses[:, :2], theirs.poses[:, :2], atol=5e-3)
    assert np.abs(wrap_angle(graph.poses[:, 2] - theirs.poses[:, 2])).max() < 1e-3


def gtsam_values(poses: np.ndarray, graph: PoseGraph):
    values = gtsam.Values()
    for n in np.flatnonzero(graph.active):
        values.insert(int(n), gtsam.Pose2(*poses[n]))
    return values


def test_offsets_are_refused():
    graph = PoseGraph()
    a, b = graph.add_node([0.0, 0.0, 0.0], robot=0), graph.add_node([1.0, 0.0, 0.0], robot=1)
    graph.add_pose_prior(a, [0.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    graph.add_observation(a, b, [1.0, 0.0, 0.0], cov=np.eye(3) * 0.01,
                          offset_a=np.array([0.1, 0.0, 0.0]))
    with pytest.raises(ValueError, match="offsets"):
        to_gtsam(graph, graph.poses)
