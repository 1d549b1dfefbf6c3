"""Weights for the symmetric copies of a belief's top mode that its evidence cannot tell apart.

In a map that looks the same under a turn, a robot that has not yet seen what breaks
the symmetry is, as far as its own scans say, on its top mode or on any of the mode's
turned copies (:mod:`estimators.mcl.map_symmetry`). A particle filter with a bounded
budget does not keep that posterior: the copies' weights drift apart through
resampling noise, and a copy left with a handful of particles is reported at a few
per cent while it is the truth about as often as the top mode. Keeping a token weight
on each copy (enough for the belief not to look confident) leaves the top mode's weight
meaning nothing: the mode weighs 0.9-0.99 and is right about half the time.

What the weights should be follows from the evidence the caller weighs (the robot's
recent scans along its odometry at each hypothesis, plus what certified teammates
told it): with log-likelihoods ``l_h`` of the hypotheses (the top mode and the copies
not rejected) and equal priors (the map cannot tell them apart), each holds the
share ``exp(l_h) / sum_k exp(l_k)`` of the mass the group holds together
(:func:`hypothesis_shares`). :func:`set_group_masses` writes those masses into a
particle set: each hypothesis' region (the particles within ``radius`` of its centre)
is scaled to its mass, and a region holding fewer particles than its share of the
set's count is topped up with its cloud (the top mode's particles turned there), in
the slots of the least likely particles outside every region, so the copies do not
starve between resamplings. Particles outside every region keep their weights.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl.modes import particle_modes

__all__ = ["TOP_MODE_HEADING_TOL", "hypothesis_shares", "load_kernels", "near_pose",
           "set_group_masses", "top_mode"]

TOP_MODE_HEADING_TOL = math.pi / 4  # rad: a mode's heading tolerance, as ``belief_modes``'
TOP_MODE_SEARCH = 4  # modes extracted to find the heaviest (greedy seeds are cells, not modes)


def hypothesis_shares(loglik: np.ndarray) -> np.ndarray:
    """``exp(l_h) / sum_k exp(l_k)``: each hypothesis' share of the group's mass (equal
    priors); ``loglik`` finite, one per hypothesis."""
    ll = np.asarray(loglik, dtype=float)
    if ll.ndim != 1 or len(ll) == 0 or not np.all(np.isfinite(ll)):
        raise ValueError(f"loglik must be a non-empty finite vector, got {ll.tolist()}")
    e = np.exp(ll - ll.max())
    return e / e.sum()


def near_pose(poses: np.ndarray, pose: np.ndarray, radius: float,
              heading_tol: float) -> np.ndarray:
    """``(N,)`` mask of the ``poses`` ``(N, 3)`` within ``radius`` m and ``heading_tol`` rad of
    ``pose``."""
    poses = np.asarray(poses, dtype=float)
    d2 = (poses[:, 0] - pose[0]) ** 2 + (poses[:, 1] - pose[1]) ** 2
    return (d2 <= radius * radius) & (np.abs(wrap_angle(poses[:, 2] - pose[2])) <= heading_tol)


def top_mode(poses: np.ndarray, weights: np.ndarray, radius: float, heading_tol: float,
             bounds: tuple[float, float, float, float]) -> tuple[np.ndarray, float]:
    """The heaviest mode of one particle set, as the dict observation's ``belief_modes``
    extracts it (:func:`estimators.mcl.modes.particle_modes`, the heaviest of its first
    ``TOP_MODE_SEARCH``: a mode split over seeding cells is not the first found): its pose
    and weight."""
    poses = np.asarray(poses, dtype=float)
    flat = np.ascontiguousarray(poses.T, dtype=np.float32).reshape(-1)
    ends = np.array([len(poses)], dtype=np.intp)
    row = particle_modes(flat, np.asarray(weights, dtype=float), ends, np.zeros((1, 2)),
                         TOP_MODE_SEARCH, radius, heading_tol, bounds)[0, 0]
    return np.array([row[1], row[2], math.atan2(row[4], row[3])]), float(row[0])


def set_group_masses(
    particles: np.ndarray, weights: np.ndarray, centres: np.ndarray, clouds: list[np.ndarray],
    masses: np.ndarray, radius: float, rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Give each hypothesis region its mass; returns new particles, weights and how many
    particles were placed.

    ``centres`` ``(H, 2)``: the regions' centres (a particle belongs to the nearest one
    within ``radius``); ``clouds``: poses ``(K_h, 3)`` to place in each region when it holds
    fewer than ``round(mass_h * N)`` particles (drawn at random, each given the region's
    mean weight before the region is scaled); ``masses`` ``(H,)`` summing to at most 1.
    Slots come from the least likely particles outside every region, then from the least
    likely of a region's particles beyond its share of the count; particles left outside
    keep their weights (the group's mass is ``1 -`` theirs, ``masses`` are scaled to it).
    """
    parts = np.array(particles, dtype=float)
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    masses = np.asarray(masses, dtype=float)
    if len(masses) != len(centres) or len(clouds) != len(centres) or masses.min() < 0:
        raise ValueError(f"need one non-negative mass and cloud per centre, got "
                         f"{len(masses)} masses, {len(clouds)} clouds, {len(centres)} centres")
    n = len(w)
    d2 = ((parts[:, None, :2] - centres[None]) ** 2).sum(axis=2)
    region = np.where(d2.min(axis=1) <= radius * radius, d2.argmin(axis=1), -1)
    # slots: the particles outside every region (least likely first), then each region's
    # particles beyond its share of the count (least likely first)
    outside = np.nonzero(region < 0)[0]
    free = [outside[np.argsort(w[outside], kind="stable")]]
    for h in range(len(centres)):
        inside = np.nonzero(region == h)[0]
        surplus = len(inside) - int(round(masses[h] * n))
        if surplus > 0:
            free.append(inside[np.argsort(w[inside], kind="stable")[:surplus]])
    free = np.concatenate(free)
    taken = 0
    for h, cloud in enumerate(clouds):
        inside = region == h
        want = int(round(masses[h] * n)) - int(inside.sum())
        k = min(want, len(free) - taken, len(cloud))
        if k <= 0:
            continue
        slots = free[taken:taken + k]
        taken += k
        parts[slots] = np.asarray(cloud, dtype=float)[rng.integers(0, len(cloud), size=k)]
        w[slots] = w[inside].mean() if inside.any() else 1.0 / n
        region[slots] = h
    rest = float(w[region < 0].sum())
    group = max(0.0, 1.0 - rest) if rest > 0 else 1.0
    scale = group / masses.sum() if masses.sum() > 0 else 0.0
    new_w = w.copy()
    for h in range(len(centres)):
        inside = region == h
        have = float(w[inside].sum())
        if have > 0:
            new_w[inside] *= masses[h] * scale / have
    return parts, new_w / new_w.sum(), taken


def load_kernels() -> None:
    """Load :func:`top_mode`'s compiled loop now (from numba's disk cache, compiling it
    the first time): otherwise the first step that weighs the copies pays it."""
    w = np.full(2, 0.5)
    particle_modes(np.zeros(6, dtype=np.float32), w, np.array([2], dtype=np.intp),
                   np.zeros((1, 2)), 1, 1.0, 1.0, (0.0, 0.0, 1.0, 1.0))
