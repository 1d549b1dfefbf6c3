"""The env step's compiled loops give exactly (bit for bit) what their numpy formulations give."""

from __future__ import annotations

import numpy as np
import pytest

from coop_loc_env import _step_kernels as k
from coop_loc_env.backends.base import gaussian_features
from coop_loc_env.sensors import _noisy_ranges
from estimators.ekf import _propagate


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal shapes and identical bits (NaN payloads and signed zeros included)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _fan_table_numpy(b, rel, r2, dirs, pose, box):
    """The numpy passes :func:`fan_ranges` replaced (hit table, then the box walls)."""
    q = rel * rel
    q = np.add(q[..., 0], q[..., 1]) - r2
    with np.errstate(invalid="ignore", divide="ignore"):
        disc = b * b
        disc -= q.T[:, :, None]
        np.sqrt(disc, out=disc)
        t = b - disc
        np.reciprocal(t, out=t)
        dist = np.divide(1.0, np.fmax.reduce(t, axis=0, initial=0.0))
        if box.size:
            wall = np.where(dirs > 0, box.reshape(2, 1, 1), 0.0)
            wall -= pose.T[:2, :, None]
            wall /= dirs
            np.abs(wall, out=wall)
            np.minimum(dist, wall[0], out=dist)
            np.minimum(dist, wall[1], out=dist)
    return dist


@pytest.mark.parametrize("seed", range(4))
def test_fan_ranges_match_the_numpy_table(seed):
    rng = np.random.default_rng(seed)
    n_fans, n_k, n_rays = 3, 7, 11
    pose = np.column_stack([rng.uniform(0, 10, (n_fans, 2)), rng.uniform(-4, 4, n_fans)])
    rel = rng.normal(0, 3, (n_fans, n_k, 2))
    r2 = rng.uniform(0.01, 1.0, (n_fans, n_k))
    r2[0, -1] = -np.inf  # a padding slot: never hit
    heading = pose[:, 2:3] + np.linspace(-np.pi, np.pi, n_rays)
    dirs = np.stack([np.cos(heading), np.sin(heading)])
    dirs[0, 1, 2] = 0.0  # a ray along an axis: a wall at infinity
    b = np.einsum("fkc,cfr->kfr", rel, dirs)
    b[2, 0, 3] = np.nan
    for box in (np.array([10.0, 10.0]), np.zeros(0)):
        out = np.empty((n_fans, n_rays))
        k.fan_ranges(b, rel, r2, dirs, pose, box, out)
        assert _same(out, _fan_table_numpy(b, rel, r2, dirs, pose, box))


def _propagate_numpy(mean, p, v, w, dt, q):
    """The numpy formulation of the EKF prediction that the compiled pass replaced."""
    n_sub, n = v.shape
    phi = np.empty((n_sub + 1, n))
    phi[0] = mean[:, 2]
    np.multiply(w, dt, out=phi[1:])
    np.add.accumulate(phi, axis=0, out=phi)
    cols = np.empty((3, 2, n_sub, n))
    cols[2] = np.array([0.0, 1.0])[:, None, None]
    np.cos(phi[:-1], out=cols[0, 0])
    np.sin(phi[:-1], out=cols[1, 0])
    ba = cols[:2, 0] * (v * np.array([dt, -dt])[:, None, None])
    ba_cum = np.add.accumulate(ba, axis=1)
    ba_tot = ba_cum[:, -1]
    np.subtract(ba_tot[:, None], ba_cum, out=cols[1::-1, 1])
    mean[:, :2] += (ba_tot * np.array([1.0, -1.0])[:, None]).T
    last = phi[-1]
    last += np.pi
    last %= 2.0 * np.pi
    last -= np.pi
    mean[:, 2] = np.minimum(last, np.nextafter(np.pi, 0.0))
    ab_tot = ba_tot[::-1].T
    p[:, :2, :] += ab_tot[:, :, None] * p[:, 2:3, :]
    p[:, :, :2] += p[:, :, 2:3] * ab_tot[:, None, :]
    q = q * (dt * dt)
    p += np.einsum("imtk,jmtk,mtk->kij", cols, cols, q)


@pytest.mark.parametrize("n_robots", [1, 4, 13, 50])
def test_ekf_prediction_matches_the_numpy_formulation(n_robots):
    rng = np.random.default_rng(n_robots)
    for n_sub in (1, 5):
        mean = rng.normal(0, [20, 20, 5], (n_robots, 3))
        a = rng.normal(size=(n_robots, 3, 3))
        p = a @ a.transpose(0, 2, 1)
        v, w = rng.normal(size=(n_sub, n_robots)), rng.normal(size=(n_sub, n_robots))
        q = rng.uniform(0, 1, (2, n_sub, n_robots))
        m1, p1, m2, p2 = mean.copy(), p.copy(), mean.copy(), p.copy()
        _propagate(m1, p1, v, w, 0.02, q.copy())
        _propagate_numpy(m2, p2, v, w, 0.02, q.copy())
        assert _same(m1, m2) and _same(p1, p2)


def test_noisy_ranges_match_the_numpy_clipping():
    rng = np.random.default_rng(5)
    ranges = rng.uniform(0, 12, (4, 30))
    ranges[0, :3] = [np.inf, 10.0, 0.0]  # no return, exactly the maximum, touching
    ranges[1, 4] = np.nan
    noise = rng.standard_normal(ranges.shape)
    out = noise.copy()
    k.noisy_ranges_into(out, ranges, 0.3, 10.0)
    expected = _noisy_ranges(ranges, 0.3, 10.0, _Replay(noise))
    assert _same(out, expected)


class _Replay:
    """A generator stand-in whose standard normals are given."""

    def __init__(self, values: np.ndarray) -> None:
        self.values = values

    def standard_normal(self, shape):
        assert tuple(shape) == self.values.shape
        return self.values.copy()


def test_scan_pooling_matches_fmin_reduceat():
    rng = np.random.default_rng(6)
    ranges = rng.uniform(0, 10, (3, 12))
    ranges[0, 4:8] = np.nan  # a bin of padding only
    ranges[1, 0] = np.nan
    scale = np.array([10.0, 10.0, 5.0])
    starts = np.array([0, 4, 8, 8, 11])  # a repeated start: that bin is one beam
    fired = np.array([True, True, False])
    out = np.full((3, 5), -1.0)
    k.pool_scans(ranges, scale, starts, fired, out)
    expected = np.fmin.reduceat(ranges / scale[:, None], starts, axis=1)
    expected[expected != expected] = 1.0
    assert _same(out[:2], expected[:2])
    assert (out[2] == -1.0).all()  # a robot that did not scan keeps its bins


def test_gaussian_features_match_the_numpy_encoding():
    rng = np.random.default_rng(7)
    mean = rng.normal(0, [20, 20, 4], (6, 3))
    a = rng.normal(size=(6, 3, 3)) * 10.0 ** rng.uniform(-7, 1, (6, 1, 1))
    cov = a @ a.transpose(0, 2, 1)
    cov[0] = 0.0  # floored variances
    cov[1, 1, 1] = np.nan
    out = gaussian_features(mean, cov, (40.0, 30.0))
    flat = cov.reshape(6, 9)
    var = np.maximum(flat[:, [0, 0, 4, 4, 8, 8]], 1e-12)
    std = np.sqrt(var)
    with np.errstate(invalid="ignore"):
        expected = np.column_stack([
            mean[:, 0] * (2.0 / 40.0) - 1.0, mean[:, 1] * (2.0 / 30.0) - 1.0,
            np.cos(mean[:, 2]), np.sin(mean[:, 2]),
            np.clip(np.log10(var[:, ::2]) * 0.5, -3.0, 2.0),
            np.clip(flat[:, [1, 2, 5]] / (std[:, :3] * std[:, 3:]), -1.0, 1.0),
        ])
    assert _same(out, expected)
