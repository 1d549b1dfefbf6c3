"""Tests of the team-MLE pose graph: residuals, analytic Jacobian, solver, marginals."""

import numpy as np
import pytest

from estimators.geometry import relative_pose, wrap_angle
from estimators.pose_graph import (
    PoseGraph,
    between,
    between_residual,
    compose,
    marginal_covariances,
    marginalize,
    observation_residual,
    optimize,
    random_team_graph,
    se2_exp,
)
from estimators.relative_metrics import relative_errors


def _numeric_jacobian(graph: PoseGraph, h: float = 1e-6) -> np.ndarray:
    var = graph.variable_index()
    base = graph.poses.copy()
    cols = []
    for node in np.flatnonzero(var >= 0)[np.argsort(var[var >= 0])]:
        for d in range(3):
            plus, minus = base.copy(), base.copy()
            plus[node, d] += h
            minus[node, d] -= h
            cols.append((graph.residuals(plus) - graph.residuals(minus)) / (2 * h))
    return np.stack(cols, axis=1)


def _mixed_graph(rng: np.random.Generator) -> PoseGraph:
    """Small graph with every factor kind: offsets, component subsets, priors, full covs."""
    g = PoseGraph()
    nodes = [g.add_node(rng.uniform(-3, 3, 3), robot=k % 3) for k in range(6)]
    g.set_fixed(nodes[0])
    cov = np.array([[0.04, 0.01, 0.0], [0.01, 0.09, 0.005], [0.0, 0.005, 0.01]])
    for i, j in [(0, 1), (1, 2), (3, 4), (4, 5), (2, 5)]:
        g.add_between(nodes[i], nodes[j], rng.uniform(-1, 1, 3), cov)
    g.add_observation(nodes[0], nodes[3], [2.0, 0.3, -1.0], std=[0.1, 0.05, 0.05])
    g.add_observation(nodes[1], nodes[4], [1.5, -0.2], std=[0.1, 0.05], components="rb")
    g.add_observation(nodes[5], nodes[2], [0.4], std=[0.05], components="o")
    g.add_observation(
        nodes[2], nodes[4], [0.7, 2.0], cov=[[0.02, 0.001], [0.001, 0.03]], components="br",
        offset_a=[0.3, -0.2, 0.4], offset_b=[-0.5, 0.1, -0.2],
    )
    g.add_pose_prior(nodes[3], [1.0, 1.0, 3.0], [0.5, 0.5, 0.3])
    g.add_prior(nodes[4:6], np.zeros((2, 3)), rng.normal(size=(4, 6)), rng.normal(size=4))
    return g


def test_analytic_jacobian_matches_finite_differences():
    rng = np.random.default_rng(11)
    g = _mixed_graph(rng)
    r, jac = g.linearize()
    assert jac.shape == (len(r), 15)  # 5 free nodes
    np.testing.assert_allclose(jac.toarray(), _numeric_jacobian(g), atol=2e-6, rtol=1e-6)
    assert g.n_residuals == 3 * 5 + 3 + 2 + 1 + 2 + 3 + 4


def test_between_residual_is_se2_log():
    rng = np.random.default_rng(2)
    xi, xj = rng.uniform(-4, 4, (50, 3)), rng.uniform(-4, 4, (50, 3))
    eps = rng.normal(0.0, 0.3, (50, 3))
    mu = compose(between(xi, xj), se2_exp(-eps))
    e, _, _ = between_residual(xi, xj, mu)
    np.testing.assert_allclose(e, eps, atol=1e-10)


def test_observation_residual_matches_geometry_and_offsets():
    rng = np.random.default_rng(4)
    xa, xb = rng.uniform(-4, 4, (20, 3)), rng.uniform(-4, 4, (20, 3))
    oa, ob = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    e, _, _ = observation_residual(xa, xb, np.zeros((20, 3)), oa, ob)
    expected = relative_pose(compose(xa, oa), compose(xb, ob))
    np.testing.assert_allclose(e[:, 0], expected[:, 0])
    np.testing.assert_allclose(wrap_angle(e[:, 1:] - expected[:, 1:]), 0.0, atol=1e-12)


def test_solver_recovers_relative_poses_within_noise():
    rng = np.random.default_rng(0)
    team = random_team_graph(10, 15, rng, room=4.0)
    g = team.graph
    start = g.poses.copy()
    res = optimize(g)
    assert res.converged and res.cost < res.initial_cost
    # 2U at the optimum is chi-square with (residuals - variables) degrees of freedom
    dof = res.n_residuals - res.n_variables
    assert abs(2 * res.cost - dof) < 4 * np.sqrt(2 * dof)
    snap = lambda p: p.reshape(10, 15, 3).transpose(1, 0, 2)  # noqa: E731
    err = relative_errors(snap(g.poses), snap(team.truth)).mean(axis=0)
    err0 = relative_errors(snap(start), snap(team.truth)).mean(axis=0)
    assert np.all(err < 0.5 * err0)
    assert err[0] < 0.3 and err[1] < 0.05 and err[2] < 0.05  # metres, rad


def test_marginal_covariances_are_consistent():
    """NEES of the last poses, averaged over seeds and robots, is near its mean 3."""
    nees = []
    for seed in range(4):
        team = random_team_graph(8, 10, np.random.default_rng(seed), room=4.0)
        optimize(team.graph)
        nodes = team.node[1:, -1]
        cov = marginal_covariances(team.graph, nodes)
        e = team.graph.poses[nodes] - team.truth[nodes]
        e[:, 2] = wrap_angle(e[:, 2])
        nees.extend(np.einsum("ki,kij,kj->k", e, np.linalg.inv(cov), e))
    assert 1.8 < np.mean(nees) < 4.5
    fixed = marginal_covariances(team.graph, [team.node[0, 0]])
    np.testing.assert_array_equal(fixed, 0.0)


def test_no_nan_when_robot_stands_still_or_robots_coincide():
    g = PoseGraph()
    a0 = g.add_node([0.0, 0.0, 0.0], fixed=True)
    a1 = g.add_node([0.0, 0.0, 0.0])
    b0 = g.add_node([0.0, 0.0, 0.0])  # on top of a0
    b1 = g.add_node([0.1, 0.0, 0.0])
    still = np.diag([1e-4, 1e-4, 1e-4])
    g.add_between(a0, a1, [0.0, 0.0, 0.0], still)
    g.add_between(b0, b1, [0.0, 0.0, 0.0], still)
    g.add_observation(a0, b0, [0.0, 0.0, 0.0], std=[0.05, 0.1, 0.05])
    g.add_observation(a1, b1, [0.0, 0.0], std=[0.05, 0.05], components="ro")
    r, jac = g.linearize()
    assert np.all(np.isfinite(r)) and np.all(np.isfinite(jac.data))
    res = optimize(g)
    assert np.isfinite(res.cost)
    assert np.all(np.isfinite(g.poses))
    cov = marginal_covariances(g, [a1, b1])
    assert np.all(np.isfinite(cov))
    np.testing.assert_allclose(g.poses[a1], 0.0, atol=1e-6)


def test_gauge_is_fixed_automatically_and_singular_information_raises():
    g = PoseGraph()
    n0 = g.add_node([1.0, 2.0, 0.3])
    n1 = g.add_node([2.0, 2.0, 0.3])
    g.add_between(n0, n1, [1.0, 0.0, 0.0], np.eye(3) * 0.01)
    optimize(g)
    assert g.fixed[n0]
    np.testing.assert_allclose(g.poses[n0], [1.0, 2.0, 0.3])
    lonely = g.add_node([5.0, 5.0, 0.0])
    other = g.add_node([6.0, 5.0, 0.0])
    g.add_observation(lonely, other, [1.0, 0.0], std=[0.1, 0.1], components="rb")
    with pytest.raises(ValueError, match="singular"):
        marginal_covariances(g, [n1])


def test_marginalization_at_optimum_preserves_solution_and_covariances():
    team = random_team_graph(5, 8, np.random.default_rng(7), room=4.0)
    g = team.graph
    optimize(g)
    keep = team.node[:, 3:].ravel()
    full_poses = g.poses[keep].copy()
    full_cov = marginal_covariances(g, team.node[:, -1])
    marginalize(g, team.node[:, :3].ravel())  # includes the fixed anchor
    assert not g.active[team.node[:, :3]].any()
    assert len(g.priors) == 1
    res = optimize(g)
    assert res.iterations <= 2
    np.testing.assert_allclose(g.poses[keep], full_poses, atol=1e-7)
    np.testing.assert_allclose(marginal_covariances(g, team.node[:, -1]), full_cov, rtol=1e-6,
                               atol=1e-10)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda g: g.add_node([0.0, np.nan, 0.0]),
         'pose must be 3 finite numbers.*nan'),
        (lambda g: g.add_between(0, 0, [0, 0, 0], np.eye(3)),
         'two distinct nodes, got i = j = 0'),
        (lambda g: g.add_between(0, 1, [0, 0, 0], -np.eye(3)),
         r'cov must be positive definite.*-1\.'),
        (lambda g: g.add_between(0, 7, [0, 0, 0], np.eye(3)),
         'node 7 is not an active node'),
        (lambda g: g.add_observation(0, 1, [1.0, 0.0], std=[0.1, 0.1]),
         r'3 finite numbers, got \[1.0, 0.0\]'),
        (lambda g: g.add_observation(0, 1, [1.0, 0.0], std=[0.1, 0.0], components="rb"),
         r'2 positive numbers, got array\(\[0.1, 0. \]\)'),
        (lambda g: g.add_observation(0, 1, [-1.0], std=[0.1], components="r"),
         r'range must be >= 0, got \[-1.0\]'),
        (lambda g: g.add_observation(0, 1, [1.0], std=[0.1], components="x"),
         "subset of 'rbo', got 'x'"),
        (lambda g: g.add_pose_prior(0, [0, 0, 0], [1.0, 0.0, 1.0]),
         r'3 positive numbers, got array\(\[1., 0., 1.\]\)'),
        (lambda g: g.add_prior([0], np.zeros(3), np.eye(2)),
         r'3 columns, got \(2, 2\)'),
    ],
)
def test_bad_input_raises_value_error(call, match):
    g = PoseGraph()
    g.add_node([0.0, 0.0, 0.0])
    g.add_node([1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=match):
        call(g)


def test_optimize_rejects_non_finite_estimates():
    g = PoseGraph()
    a = g.add_node([0.0, 0.0, 0.0], fixed=True)
    b = g.add_node([1.0, 0.0, 0.0])
    g.add_between(a, b, [1.0, 0.0, 0.0], np.eye(3) * 0.01)
    g.poses[b, 0] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        optimize(g)


def test_factor_selection_subgraph_and_remove():
    team = random_team_graph(3, 4, np.random.default_rng(7))
    g = team.graph
    g.add_pose_prior(int(team.node[1, 0]), g.poses[team.node[1, 0]] + 0.1, [0.5, 0.5, 0.2])
    everything = g.factors_touching(np.ones(g.n_nodes, bool))
    assert everything.between.all() and everything.observation.all() and all(everything.priors)
    whole = g.subgraph(np.arange(g.n_nodes), everything)
    assert whole.cost() == pytest.approx(g.cost(), rel=1e-12)

    gone = np.zeros(g.n_nodes, bool)
    gone[team.node[:, 0]] = True  # every robot's first pose
    hit = g.factors_touching(gone)
    assert hit.between.sum() == 3 and hit.priors == [True]
    touched = np.unique(np.concatenate(g.selection_nodes(hit)))
    part = g.subgraph(touched, hit)
    assert part.n_nodes == len(touched) and part.n_between == 3
    assert part.n_observations == int(hit.observation.sum())
    cost_before = g.cost()
    g.remove(hit, np.flatnonzero(gone))
    assert not g.active[gone].any() and g.active[~gone].all()
    assert g.n_between == len(hit.between) - 3 and not g.priors
    # The removed factors' cost moved to the sub-graph; nothing else changed.
    assert g.cost() + part.cost() == pytest.approx(cost_before, rel=1e-12)
    with pytest.raises(ValueError, match="is not an active node"):
        g.check_nodes([team.node[0, 1], team.node[0, 0]])
