"""EKF: consistency in the loop, gating, cooperative updates, numerics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binom, chi2

import coop_loc_env
from estimators.ekf import PoseEKF, chi2_threshold, relative_measurement
from estimators.geometry import relative_pose, wrap_angle


def _nees(info: dict) -> float:
    e = info["est_pose"] - info["true_pose"]
    e[2] = wrap_angle(e[2])
    return float(e @ np.linalg.solve(info["pose_cov"], e))


def test_filter_is_consistent_with_gps_over_a_long_run():
    """Mean NEES lies in the 95 % chi-square band (3 dof), Monte Carlo over runs and robots.

    Each of 40 independent episodes (5 robots, 20 s of odometry, DGPS and compass)
    contributes its robots' final NEES, so the 200 samples are independent and
    the band ``chi2(3N) / N`` is exact. The robots circle 8 m apart so that no
    collision (unmodelled wheel slip) occurs; cooperative updates and multipath
    outliers (which the gate handles, tested below) are off.
    """
    starts = tuple((8.0 + 6.0 * i, 20.0 + (-4.0) ** (i % 2), 0.0) for i in range(5))
    kw = dict(n_robots=5, steep_patches=0, n_random_trees=0, n_random_rocks=0,
              start_poses=starts, max_cycles=200, cooperative_updates=False,
              gps_multipath_prob=0.0)
    samples = []
    for seed in range(40):
        env = coop_loc_env.parallel_env(**kw)
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        turn = rng.choice([-1.0, 1.0], size=5) * rng.uniform(0.25, 0.5, size=5)
        contacts = 0
        while env.agents:
            _, _, _, _, infos = env.step(
                {a: np.array([0.4, turn[i]], np.float32) for i, a in enumerate(env.agents)}
            )
            contacts += sum(i["collisions"] for i in infos.values())
        assert contacts == 0
        samples += [_nees(i) for i in infos.values()]
    n = len(samples)
    lo, hi = chi2.ppf(0.025, 3 * n) / n, chi2.ppf(0.975, 3 * n) / n
    assert lo <= np.mean(samples) <= hi, (np.mean(samples), lo, hi)


def test_gate_rejects_injected_outliers_and_accepts_inliers():
    """20 000 genuine fixes (innovation covariance exactly ``S``): the default 99 % gate
    rejects a binomial(20 000, 0.01) count, within its two-sided 99.9 % band 155-248
    (197 here; a 99.9 % gate would reject about 20, a threshold 10 % higher about 126).
    Outliers 10 m off are all rejected and leave the means alone."""
    n = 20_000
    rng = np.random.default_rng(0)
    ekf = PoseEKF(np.zeros((n, 3)), np.diag([0.04, 0.04, 0.01]))
    r = np.repeat(np.eye(2)[None] * 0.09, n, axis=0)
    inlier = rng.multivariate_normal([0, 0], np.eye(2) * 0.13, size=n)
    ok = ekf.update_position(np.arange(n), inlier, r)
    lo, hi = binom.ppf(0.0005, n, 0.01), binom.isf(0.0005, n, 0.01)
    assert lo <= np.count_nonzero(~ok) <= hi, (np.count_nonzero(~ok), lo, hi)
    before = ekf.mean.copy()
    outliers = np.tile([8.0, -6.0], (n, 1))
    ok = ekf.update_position(np.arange(n), outliers, r)
    assert not ok.any()
    np.testing.assert_array_equal(ekf.mean, before)


def test_gate_decides_at_the_chi2_quantile():
    """Fixes and headings whose gate statistic is 5 % under the 0.99 chi-square quantile
    (2 dof, 1 dof) pass the default gate, 5 % over it fail."""
    cov = np.diag([0.04, 0.04, 0.01])
    ekf = PoseEKF(np.zeros((2, 3)), cov)
    q2 = chi2.ppf(0.99, 2)
    z = np.array([[np.sqrt(0.13 * 0.95 * q2), 0.0], [0.0, -np.sqrt(0.13 * 1.05 * q2)]])
    ok = ekf.update_position(np.arange(2), z, np.repeat(np.eye(2)[None] * 0.09, 2, axis=0))
    np.testing.assert_array_equal(ok, [True, False])
    ekf = PoseEKF(np.zeros((2, 3)), cov)
    q1 = chi2.ppf(0.99, 1)
    h = np.array([np.sqrt(0.02 * 0.95 * q1), -np.sqrt(0.02 * 1.05 * q1)])
    np.testing.assert_array_equal(ekf.update_heading(np.arange(2), h, np.full(2, 0.01)),
                                  [True, False])


def test_chi2_threshold_matches_scipy_and_rejects_bad_probability():
    assert chi2_threshold(0.99, 2) == pytest.approx(chi2.ppf(0.99, 2))
    with pytest.raises(ValueError, match="1.5"):
        chi2_threshold(1.5, 2)


def test_cooperative_update_shrinks_covariance_of_robot_without_gps():
    ekf = PoseEKF(
        np.array([[0.0, 0.0, 0.0], [3.0, 1.0, 0.5]]),
        np.stack([np.diag([0.01, 0.01, 0.001]), np.diag([4.0, 4.0, 0.3])]),
    )
    truth = np.array([[0.0, 0.0, 0.0], [3.5, 0.5, 0.4]])
    rng = np.random.default_rng(1)
    errors = [np.hypot(*(ekf.mean[1, :2] - truth[1, :2]))]
    r = np.diag([0.05**2, 0.02**2, 0.05**2])[None]
    for _ in range(5):
        # Robot 1 drives 1 s on odometry alone (no GPS): its covariance grows ...
        ekf.predict_sequence(np.zeros((10, 2)), np.zeros((10, 2)), 0.1, [0.0, 0.5], [0.0, 0.05])
        before = np.trace(ekf.cov[1])
        z = relative_pose(truth[0], truth[1]) + rng.normal(0, [0.05, 0.02, 0.05])
        ok = ekf.update_relative([0], [1], z[None], r)
        assert ok.all()
        # ... and shrinks at every cooperative update.
        assert np.trace(ekf.cov[1]) < before
        errors.append(np.hypot(*(ekf.mean[1, :2] - truth[1, :2])))
    assert errors[-1] < 0.2 < errors[0]
    # The well-localized observer is not made worse.
    assert np.trace(ekf.cov[0]) <= np.trace(np.diag([0.01, 0.01, 0.001])) + 10 * 0.011


def test_cartesian_model_matches_paper_equation_3():
    """H = [I, -I] (the paper's naive joint update) moves both robots to the measured gap."""
    ekf = PoseEKF(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.eye(3) * 0.5)
    z = np.array([[-1.2, 0.0, 0.0]])  # x_a - x_b
    ok = ekf.update_relative([0], [1], z, np.eye(3)[None] * 0.01, model="cartesian",
                             fusion="naive", gate_prob=1.0)
    assert ok.all()
    assert ekf.mean[1, 0] - ekf.mean[0, 0] == pytest.approx(1.2, abs=0.05)
    assert ekf.mean[0, 0] < 0 < ekf.mean[1, 0] - 1.0


def test_ci_fusion_never_inflates_a_covariance():
    """With unknown correlation a relative fix between equals cannot sharpen either marginal."""
    rng = np.random.default_rng(2)
    for _ in range(20):
        a = rng.normal(size=(2, 3, 3))
        cov = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(3)
        ekf = PoseEKF(rng.normal(size=(2, 3)) * 3, cov)
        before = np.trace(ekf.cov, axis1=1, axis2=2)
        z = relative_pose(*ekf.mean) + rng.normal(0, 0.1, 3)
        ekf.update_relative([0], [1], z[None], np.eye(3)[None] * 0.01, gate_prob=1.0)
        assert np.all(np.trace(ekf.cov, axis1=1, axis2=2) <= before + 1e-12)


def test_relative_measurement_jacobian_matches_finite_differences():
    rng = np.random.default_rng(3)
    xa = rng.normal(size=(5, 3))
    xb = xa + rng.normal(size=(5, 3)) * 2
    h, ja, jb = relative_measurement(xa, xb)
    eps = 1e-6
    for j in range(3):
        d = np.zeros(3)
        d[j] = eps
        num_a = (relative_measurement(xa + d, xb)[0] - relative_measurement(xa - d, xb)[0])
        num_b = (relative_measurement(xa, xb + d)[0] - relative_measurement(xa, xb - d)[0])
        np.testing.assert_allclose(wrap_angle(num_a) / (2 * eps), ja[:, :, j], atol=1e-5)
        np.testing.assert_allclose(wrap_angle(num_b) / (2 * eps), jb[:, :, j], atol=1e-5)
    np.testing.assert_allclose(h, relative_pose(xa, xb), atol=1e-12)


def test_covariances_stay_symmetric_positive_definite():
    rng = np.random.default_rng(4)
    ekf = PoseEKF(np.zeros((4, 3)), np.eye(3) * 1e-6)
    for _ in range(300):
        ekf.predict_sequence(rng.normal(1, 0.1, (5, 4)), rng.normal(0, 1, (5, 4)), 0.02,
                             0.0025, 0.0025)
        ekf.update_position(np.arange(4), rng.normal(0, 1e-3, (4, 2)),
                            np.repeat(np.eye(2)[None] * 1e-8, 4, 0), gate_prob=1.0)
        ekf.update_heading(np.arange(4), rng.normal(0, 1e-3, 4), np.full(4, 1e-10),
                           gate_prob=1.0)
        ekf.update_relative([0, 2], [1, 3], np.abs(rng.normal(1, 0.1, (2, 3))),
                            np.repeat(np.eye(3)[None] * 1e-8, 2, 0), gate_prob=1.0)
    np.testing.assert_allclose(ekf.cov, np.swapaxes(ekf.cov, 1, 2), atol=0)
    assert np.all(np.linalg.eigvalsh(ekf.cov) > 0)


def test_predict_sequence_equals_sequential_predictions():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(3, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) + np.eye(3)
    mean = rng.normal(size=(3, 3))
    one, many = PoseEKF(mean, cov), PoseEKF(mean, cov)
    v, w = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    qv, qw = rng.random((7, 3)), rng.random((7, 3))
    for k in range(7):
        one.predict(v[k], w[k], 0.05, qv[k], qw[k])
    many.predict_sequence(v, w, 0.05, qv, qw)
    np.testing.assert_allclose(one.mean, many.mean, atol=1e-12)
    np.testing.assert_allclose(one.cov, many.cov, atol=1e-12)


def test_predict_sequence_stacked_equals_sequential_predictions():
    """The env's entry point (variances stacked in one (2, T, n) array) is the public
    predict_sequence, and both equal T single predict() steps."""
    rng = np.random.default_rng(6)
    a = rng.normal(size=(4, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) + np.eye(3)
    mean = rng.normal(size=(4, 3))
    one, seq, stacked = PoseEKF(mean, cov), PoseEKF(mean, cov), PoseEKF(mean, cov)
    v, w = rng.normal(size=(6, 4)), rng.normal(size=(6, 4))
    q = rng.random((2, 6, 4))
    q_before = q.copy()
    for k in range(6):
        one.predict(v[k], w[k], 0.04, q[0, k], q[1, k])
    seq.predict_sequence(v, w, 0.04, q[0], q[1])
    stacked.predict_sequence_stacked(v, w, 0.04, q)
    assert np.array_equal(q, q_before)  # read only
    np.testing.assert_array_equal(stacked.mean, seq.mean)
    np.testing.assert_array_equal(stacked.cov, seq.cov)
    np.testing.assert_allclose(one.mean, stacked.mean, atol=1e-12)
    np.testing.assert_allclose(one.cov, stacked.cov, atol=1e-12)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="NaN"):
        PoseEKF(np.array([[0.0, np.nan, 0.0]]), np.eye(3))
    with pytest.raises(ValueError, match="shape"):
        PoseEKF(np.zeros((2, 3)), np.eye(2))
    ekf = PoseEKF(np.zeros((2, 3)), np.eye(3))
    with pytest.raises(ValueError, match="itself"):
        ekf.update_relative([0], [0], np.ones((1, 3)), np.eye(3)[None])
    with pytest.raises(ValueError, match="NaN"):
        ekf.update_position([0], np.array([[np.nan, 0.0]]), np.eye(2)[None])


def _reference_update(mean, cov, idx, z, h_rows, r, angle, gate):
    """Textbook gated EKF update with a selection Jacobian, one robot at a time."""
    mean, cov = mean.copy(), cov.copy()
    ok = []
    for i, zi, ri in zip(idx, z, r, strict=True):
        jac = np.eye(3)[h_rows]
        nu = zi - mean[i, h_rows]
        if angle:
            nu = wrap_angle(nu)
        s = jac @ cov[i] @ jac.T + ri
        accept = nu @ np.linalg.solve(s, nu) <= gate
        ok.append(accept)
        if accept:
            gain = cov[i] @ jac.T @ np.linalg.inv(s)
            mean[i] += gain @ nu
            mean[i, 2] = wrap_angle(mean[i, 2])
            a = np.eye(3) - gain @ jac
            p = a @ cov[i] @ a.T + gain @ ri @ gain.T
            cov[i] = 0.5 * (p + p.T)
    return mean, cov, np.array(ok)


@pytest.mark.parametrize("order", ["all", "permuted", "subset"])
def test_position_and_heading_updates_match_a_reference(order):
    rng = np.random.default_rng(7)
    n = 6
    a = rng.standard_normal((n, 3, 3))
    cov = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(3)
    mean = rng.standard_normal((n, 3)) * [5.0, 5.0, 3.0]
    idx = {"all": np.arange(n), "permuted": rng.permutation(n), "subset": np.array([4, 1])}[order]
    k = len(idx)
    z_xy = mean[idx, :2] + rng.standard_normal((k, 2)) * 2.0
    z_xy[0] += 100.0  # an outlier the gate rejects
    r = np.repeat(0.3 * np.eye(2)[None], k, axis=0)
    ekf = PoseEKF(mean, cov)
    ref_mean, ref_cov, ref_ok = _reference_update(
        ekf.mean, ekf.cov, idx, z_xy, [0, 1], r, False, chi2_threshold(0.99, 2)
    )
    ok = ekf.update_position(idx, z_xy, r)
    np.testing.assert_array_equal(ok, ref_ok)
    assert not ok[0] and ok[1:].any()
    np.testing.assert_allclose(ekf.mean, ref_mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ekf.cov, ref_cov, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(ekf.cov, ekf.cov.transpose(0, 2, 1))
    # Compass: headings near +-pi exercise the wrapping of innovation and state.
    z_phi = wrap_angle(ekf.mean[idx, 2] + np.pi - 0.05)
    var = np.full(k, 0.2)
    before_mean, before_cov = ekf.mean.copy(), ekf.cov.copy()
    ok = ekf.update_heading(idx, z_phi, var)
    ref_mean, ref_cov, ref_ok = _reference_update(
        before_mean, before_cov, idx, z_phi[:, None], [2], var.reshape(-1, 1, 1), True,
        chi2_threshold(0.99, 1),
    )
    np.testing.assert_array_equal(ok, ref_ok)
    np.testing.assert_allclose(ekf.mean, ref_mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ekf.cov, ref_cov, rtol=1e-12, atol=1e-12)
    assert np.all(np.abs(ekf.mean[:, 2]) <= np.pi)


def test_generic_update_equals_position_update():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((4, 3, 3))
    cov = a @ a.transpose(0, 2, 1) + np.eye(3)
    mean = rng.standard_normal((4, 3))
    idx = np.array([2, 0, 3])
    z = mean[idx, :2] + 0.5
    r = np.repeat(0.5 * np.eye(2)[None], 3, axis=0)
    one, two = PoseEKF(mean, cov), PoseEKF(mean, cov)
    jac = np.repeat(np.eye(3)[None, :2], 3, axis=0)
    ok1 = one.update(idx, z, two.mean[idx, :2], jac, r)
    ok2 = two.update_position(idx, z, r)
    np.testing.assert_array_equal(ok1, ok2)
    np.testing.assert_allclose(one.mean, two.mean, rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(one.cov, two.cov, rtol=1e-13, atol=1e-14)
    with pytest.raises(ValueError, match="NaN"):
        two.update_position(idx, np.full((3, 2), np.nan), r)
    with pytest.raises(ValueError, match="NaN"):
        two.update_heading(idx, [0.0, np.inf, 0.0], np.ones(3))
    assert two.update_heading([], [], []).shape == (0,)


def _reference_ci_weight(pa, pb, jac, r):
    """The grid search on the full 6x6 inflated covariances (the direct form)."""
    weights = np.linspace(0.05, 0.95, 10)
    costs = []
    for w in weights:
        cost = []
        for i in range(len(pa)):
            p = np.zeros((6, 6))
            p[:3, :3], p[3:, 3:] = pa[i] / w, pb[i] / (1 - w)
            s = jac[i] @ p @ jac[i].T + r[i]
            post = p - p @ jac[i].T @ np.linalg.solve(s, jac[i] @ p)
            cost.append(
                min(np.trace(post[:3, :3]), np.trace(pa[i]))
                + min(np.trace(post[3:, 3:]), np.trace(pb[i]))
            )
        costs.append(cost)
    return weights[np.argmin(np.array(costs), axis=0)]


@pytest.mark.parametrize("model", ["rbo", "cartesian"])
@pytest.mark.parametrize("dims", [(0, 1, 2), (0, 1)])
@pytest.mark.parametrize("k", [2, 40])  # LAPACK inverses, cofactors (from 4 pairs on)
def test_ci_weight_matches_the_direct_grid_search(model, dims, k):
    from estimators.relative_model import best_ci_weight, stacked_relative_measurement

    rng = np.random.default_rng(11)
    a = rng.standard_normal((2, k, 3, 3)) * rng.uniform(0.05, 3.0, (2, k, 1, 1))
    pab = a @ a.transpose(0, 1, 3, 2) + 1e-3 * np.eye(3)
    xa, xb = rng.standard_normal((2, k, 3)) * [4.0, 4.0, 3.0]
    _, jac = stacked_relative_measurement(xa, xb, model)
    r = np.repeat(np.diag([0.05, 0.01, 0.02])[None], k, axis=0)
    jac, r = jac[:, list(dims)], r[:, list(dims)][:, :, list(dims)]
    got = best_ci_weight(pab, jac, r)
    np.testing.assert_array_equal(got, _reference_ci_weight(pab[0], pab[1], jac, r))


def test_relative_measurement_matches_its_formulas():
    rng = np.random.default_rng(5)
    xa, xb = rng.standard_normal((2, 30, 3)) * [5.0, 5.0, 3.0]
    xb[0, :2] = xa[0, :2]  # coinciding estimates: range floored at 1 mm
    h, ja, jb = relative_measurement(xa, xb)
    dx, dy = xb[:, 0] - xa[:, 0], xb[:, 1] - xa[:, 1]
    q = np.maximum(dx * dx + dy * dy, 1e-6)
    rng_ = np.sqrt(q)
    np.testing.assert_array_equal(h[:, 0], rng_)
    np.testing.assert_array_equal(h[:, 1], wrap_angle(np.arctan2(dy, dx) - xa[:, 2]))
    np.testing.assert_array_equal(h[:, 2], wrap_angle(xb[:, 2] - xa[:, 2]))
    zero, one = np.zeros(30), np.ones(30)
    want_a = np.stack(
        [[-dx / rng_, -dy / rng_, zero], [dy / q, -dx / q, -one], [zero, zero, -one]]
    ).transpose(2, 0, 1)
    want_b = np.stack(
        [[dx / rng_, dy / rng_, zero], [-dy / q, dx / q, zero], [zero, zero, one]]
    ).transpose(2, 0, 1)
    np.testing.assert_array_equal(ja, want_a)
    np.testing.assert_array_equal(jb, want_b)
    h, ja, jb = relative_measurement(xa, xb, "cartesian")
    want = xa - xb
    want[:, 2] = wrap_angle(want[:, 2])
    np.testing.assert_array_equal(h, want)
    np.testing.assert_array_equal(ja, np.broadcast_to(np.eye(3), (30, 3, 3)))
    np.testing.assert_array_equal(jb, np.broadcast_to(-np.eye(3), (30, 3, 3)))
    with pytest.raises(ValueError, match="model"):
        relative_measurement(xa, xb, "polar")
    with pytest.raises(ValueError, match="shape"):
        relative_measurement(xa, xb[:3])


def test_rounds_limit_keeps_the_first_rounds():
    from estimators.relative_model import disjoint_rounds

    rng = np.random.default_rng(2)
    a = rng.integers(0, 12, 80)
    b = (a + rng.integers(1, 12, 80)) % 12
    every = disjoint_rounds(a, b, 12)
    assert sum(len(x) for x in every) == 80
    for rows in every:
        robots = np.concatenate([a[rows], b[rows]])
        assert len(np.unique(robots)) == len(robots)
    for limit in (0, 1, 3):
        got = disjoint_rounds(a, b, 12, limit)
        assert len(got) == min(limit, len(every))
        for x, y in zip(got, every, strict=False):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("fusion", ["ci", "naive"])
def test_relative_update_with_partial_dims_and_rounds(fusion):
    rng = np.random.default_rng(9)
    n = 8
    mean = rng.uniform(0, 10, (n, 3))
    ekf = PoseEKF(mean, np.diag([0.5, 0.5, 0.1]))
    ekf.cov[::2] *= 10.0
    ia = np.array([0, 2, 4, 0, 6])
    ib = np.array([1, 3, 5, 7, 1])
    z = relative_pose(mean[ia], mean[ib]) + rng.normal(0, 0.01, (5, 3))
    r = np.repeat(np.diag([0.05, 0.01, 0.02])[None], 5, axis=0)
    before = ekf.cov.copy()
    ok = ekf.update_relative(ia, ib, z, r, dims=(0, 1), fusion=fusion, max_rounds=1)
    assert ok.tolist() == [True, True, True, False, False]  # 0 and 1 are in round 1 already
    traces = np.trace(ekf.cov, axis1=1, axis2=2)
    shrink = np.trace(before, axis1=1, axis2=2) - traces
    assert np.all(shrink >= -1e-12)  # no robot's uncertainty grows, with either fusion
    assert np.all(shrink[[0, 2, 4]] > 0.5)  # the uncertain observed robots (cov x 10) gain
    np.testing.assert_array_equal(ekf.cov[[6, 7]], before[[6, 7]])  # pairs left to round 2
    if fusion == "naive":  # a Kalman update as if independent: P shrinks in every direction
        assert np.linalg.eigvalsh(before - ekf.cov).min() > -1e-12
        assert np.all(shrink[[1, 3, 5]] > 0)
    else:  # covariance intersection keeps the confident robot's prior
        np.testing.assert_array_equal(ekf.cov[[1, 3, 5]], before[[1, 3, 5]])
    np.testing.assert_array_equal(ekf.cov, ekf.cov.transpose(0, 2, 1))
    assert np.all(np.abs(ekf.mean[:, 2]) <= np.pi)


def test_cofactors_give_the_inverse_and_determinant():
    from estimators.relative_model import _cofactors3

    rng = np.random.default_rng(4)
    a = rng.standard_normal((5, 7, 3, 3))
    cof, det = _cofactors3(a)
    np.testing.assert_allclose(det, np.linalg.det(a), rtol=1e-12)
    np.testing.assert_allclose(cof.swapaxes(-1, -2) / det[..., None, None], np.linalg.inv(a),
                               rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("scale", [1.0, 2.5])
def test_backend_step_predicts_with_textbook_variances(scale):
    """EKFBackend.step on a step without fixes, headings or detections is the public
    predict_sequence with var = scale * (encoder var + (slip_std * odometry)^2)."""
    import copy
    import dataclasses

    from coop_loc_env.sensors import Detections

    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, start_region=None,
                                    ekf_process_noise_scale=scale)
    env.reset(seed=1)
    backend = env.unwrapped.backends[0]
    cfg = backend.cfg
    rng = np.random.default_rng(3)
    for _ in range(5):
        env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
    before = copy.deepcopy(backend)
    env.step({a: rng.uniform(-1, 1, 2) for a in env.agents})
    readings, active = env.unwrapped.last_readings, np.ones(4, bool)
    replay = copy.deepcopy(before)
    replay.step(readings, active)  # the env's own call, replayed on a copy
    assert np.array_equal(replay.ekf.mean, backend.ekf.mean)
    assert np.array_equal(replay.ekf.cov, backend.ekf.cov)
    none = np.zeros(4, bool)
    quiet = dataclasses.replace(readings, gps_mask=none, compass_mask=none,
                                detections=Detections(), bumper=none)
    mine = copy.deepcopy(before)
    mine.step(quiet, active)
    ref = copy.deepcopy(before.ekf)  # the same filter state, predicted by the public call
    odo = readings.odometry
    var_v = scale * (cfg.odom_v_std**2 + (cfg.slip_std * odo[..., 0]) ** 2)
    var_w = scale * (cfg.odom_w_std**2 + (cfg.slip_std * odo[..., 1]) ** 2)
    ref.predict_sequence(odo[..., 0], odo[..., 1], cfg.dt / cfg.odometry_substeps, var_v, var_w)
    assert np.array_equal(mine.ekf.mean, ref.mean) and np.array_equal(mine.ekf.cov, ref.cov)
    assert not np.array_equal(ref.cov, before.ekf.cov)  # the step did predict


def test_predict_with_idx_and_scalar_variances_matches_a_one_step_sequence():
    rng = np.random.default_rng(8)
    a = rng.normal(size=(4, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) + np.eye(3)
    mean = rng.normal(size=(4, 3))
    part, seq = PoseEKF(mean, cov), PoseEKF(mean[[3, 1]], cov[[3, 1]])
    start = part.mean.copy(), part.cov.copy()
    v, w = rng.normal(size=2), rng.normal(size=2)
    part.predict(v, w, 0.1, 0.02, [0.001, 0.003], idx=np.array([3, 1]))
    seq.predict_sequence(v[None], w[None], 0.1, 0.02, np.array([[0.001, 0.003]]))
    assert np.array_equal(part.mean[[3, 1]], seq.mean) and np.array_equal(part.cov[[3, 1]], seq.cov)
    # The robots not selected keep their beliefs.
    assert np.array_equal(part.mean[[0, 2]], start[0][[0, 2]])
    assert np.array_equal(part.cov[[0, 2]], start[1][[0, 2]])


def test_wrap_angle_in_place_equals_wrap_angle():
    from estimators.geometry import wrap_angle, wrap_angle_in_place

    angles = np.concatenate([np.linspace(-20.0, 20.0, 401), [-np.pi, np.pi, 0.0, 3 * np.pi]])
    out = angles.copy()
    wrap_angle_in_place(out)
    np.testing.assert_array_equal(out, wrap_angle(angles))
    assert out.min() >= -np.pi and out.max() < np.pi
