"""Tests of the piecewise-constant density tree."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.mcl.density_tree import DensityTree

LOW3 = np.array([0.0, 0.0, -np.pi])
HIGH3 = np.array([10.0, 6.0, np.pi])


def test_leaf_densities_integrate_to_one():
    rng = np.random.default_rng(0)
    x = rng.normal([5.0, 3.0, 0.0], [0.5, 0.3, 0.2], (2000, 3))
    tree = DensityTree(x, low=LOW3, high=HIGH3)
    assert tree.n_leaves > 20
    assert tree.integral() == pytest.approx(1.0, abs=1e-12)
    lo, hi, dens = tree.leaves()
    # the leaves tile the domain: their volumes add up to the box
    assert np.prod(hi - lo, axis=1).sum() == pytest.approx(tree.volume, rel=1e-12)
    # each leaf's density is the share of the samples inside it over its volume
    inside = np.all((x[:, None, :] >= lo) & (x[:, None, :] < hi), axis=2)
    assert np.all(inside.sum(axis=1) == 1)
    np.testing.assert_allclose(dens, inside.mean(axis=0) / np.prod(hi - lo, axis=1), rtol=1e-12)


def test_monte_carlo_integral_of_pdf_over_the_domain_is_one():
    rng = np.random.default_rng(1)
    # a broad mixture so that plain Monte Carlo has a small variance
    x = np.vstack([
        rng.uniform([1, 1, -np.pi], [9, 5, np.pi], (1500, 3)),
        rng.normal([3.0, 4.0, 1.0], [1.0, 0.6, 0.5], (500, 3)),
    ])
    x[:, 2] = np.clip(x[:, 2], -np.pi, np.pi - 1e-9)
    x[:, :2] = np.clip(x[:, :2], [0, 0], [10 - 1e-9, 6 - 1e-9])
    tree = DensityTree(x, low=LOW3, high=HIGH3)
    u = rng.uniform(LOW3, HIGH3, (400_000, 3))
    vals = tree.pdf(u) * tree.volume
    est, se = vals.mean(), vals.std() / np.sqrt(vals.size)
    assert abs(est - 1.0) < 4 * se
    assert se < 0.01


def test_pdf_recovers_a_uniform_box_and_is_zero_far_away():
    rng = np.random.default_rng(2)
    x = rng.uniform([2.0, 1.0], [4.0, 2.0], (4000, 2))  # density 0.5 on a 2 m^2 box
    tree = DensityTree(x, low=np.array([0.0, 0.0]), high=np.array([8.0, 4.0]))
    inner = rng.uniform([2.3, 1.2], [3.7, 1.8], (500, 2))
    np.testing.assert_allclose(tree.pdf(inner).mean(), 0.5, rtol=0.1)
    far = rng.uniform([5.0, 2.5], [8.0, 4.0], (500, 2))
    assert np.all(tree.pdf(far) == 0.0)
    # outside the domain the density is zero, inside it is finite
    assert tree.pdf(np.array([[-1.0, 1.0], [8.0, 1.0], [3.0, 5.0]])).tolist() == [0, 0, 0]


def test_weights_set_the_mass_of_each_cluster():
    rng = np.random.default_rng(3)
    a = rng.normal([2.0, 2.0], 0.1, (1000, 2))
    b = rng.normal([7.0, 4.0], 0.1, (1000, 2))
    w = np.r_[np.full(1000, 0.8), np.full(1000, 0.2)]
    tree = DensityTree(np.vstack([a, b]), weights=w, low=np.zeros(2), high=np.array([10.0, 6.0]))
    lo, hi, dens = tree.leaves()
    mass = dens * np.prod(hi - lo, axis=1)
    centre = 0.5 * (lo + hi)
    left = centre[:, 0] < 5.0
    assert mass[left].sum() == pytest.approx(0.8, abs=1e-9)
    assert mass[~left].sum() == pytest.approx(0.2, abs=1e-9)


def test_splits_halve_the_longest_scaled_dimension():
    rng = np.random.default_rng(4)
    x = rng.uniform([0, 0, -np.pi], [10, 6, np.pi], (50, 3))
    tree = DensityTree(x, low=LOW3, high=HIGH3, leaf_size=49)
    lo, hi, _ = tree.leaves()
    assert len(lo) == 2  # one split: along x (10 m) at its midpoint
    assert sorted(hi[:, 0].tolist()) == [5.0, 10.0]
    # scaling the heading axis by 2 m/rad makes it the longest (2 * 2 pi > 10)
    tree = DensityTree(x, low=LOW3, high=HIGH3, leaf_size=49, scale=np.array([1.0, 1.0, 2.0]))
    lo, hi, _ = tree.leaves()
    assert sorted(hi[:, 2].tolist()) == pytest.approx([0.0, np.pi])


def test_resolution_follows_sample_density():
    rng = np.random.default_rng(5)
    x = np.vstack([rng.normal([2.0, 2.0], 0.05, (1900, 2)), rng.uniform(0, 6, (100, 2))])
    tree = DensityTree(x, low=np.zeros(2), high=np.full(2, 6.0))
    lo, hi, _ = tree.leaves()
    vol = np.prod(hi - lo, axis=1)
    near = np.all(np.abs(0.5 * (lo + hi) - 2.0) < 0.2, axis=1)
    assert np.median(vol[near]) < 0.01 * np.median(vol[~near])
    assert tree.pdf(np.array([2.0, 2.0])) > 100 * tree.pdf(np.array([5.0, 5.0])) > 0


def test_default_domain_is_the_sample_bounding_box():
    x = np.array([[0.0, 0.0], [1.0, 2.0], [0.5, 1.0]])
    tree = DensityTree(x)
    assert np.all(tree.pdf(x) > 0)
    assert tree.integral() == pytest.approx(1.0)


def test_bad_input_raises():
    x = np.zeros((5, 2))
    with pytest.raises(ValueError, match="outside the domain"):
        DensityTree(x + 3.0, low=np.zeros(2), high=np.ones(2))
    with pytest.raises(ValueError, match="finite"):
        DensityTree(np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="weights"):
        DensityTree(x, weights=np.zeros(5), low=-np.ones(2), high=np.ones(2))
    with pytest.raises(ValueError, match="high > low"):
        DensityTree(x, low=np.ones(2), high=np.ones(2))
    with pytest.raises(ValueError, match="trailing axis"):
        DensityTree(x, low=-np.ones(2), high=np.ones(2)).pdf(np.zeros((3, 3)))
