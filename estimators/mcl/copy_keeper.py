"""The per-step passes of keeping a belief's symmetric copies, compiled where they loop.

:func:`filter_mode` is :func:`~estimators.mcl.detection_consistency.main_mode`'s mask
of a filter's particles and the weight in it; :func:`top_up_copies` gives every turned
copy of a main mode its share of the weight as
:func:`~estimators.mcl.detection_consistency.widen` would, copy after copy. Both give
bit for bit what that numpy code gives (``tests/estimators/mcl/test_copy_keeper.py``);
the compiled loops (:mod:`estimators.mcl._keeper_kernels`) turn the copies, drop those
off the free space and find a copy that already holds its share, which is most of
them at most steps, without a Python pass over the particles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from estimators.mcl._keeper_kernels import (
    SAFE,
    copy_masks,
    disc_weight_bound,
    lightest_outside,
    mode_mask,
    topped_up_weights,
    turned_free,
    uniform_centre,
    weighted_median,
)
from estimators.mcl.detection_consistency import main_mode, widen
from estimators.mcl.map_symmetry import MapSymmetry
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.team import ParticleSet

__all__ = ["filter_mode", "load_kernels", "mode_weight_below", "top_up_copies"]


def filter_mode(ps: ParticleSet, radius: float) -> tuple[np.ndarray, float]:
    """``mode = main_mode(world_xy, ps.weights, radius)[1]`` and ``ps.weights[mode].sum()``
    for a particle set (world positions: its float32 state plus its origin)."""
    ox, oy = ps.origin_xy
    state = ps.state
    if not state.flags.c_contiguous:
        state = np.ascontiguousarray(state)
    mask, mass, ok = mode_mask(state, ox, oy, ps.weights, float(radius))
    if ok:
        return mask, mass
    xy = np.column_stack([state[0] + ox, state[1] + oy])
    _, mask = main_mode(xy, ps.weights, radius)
    return mask, float(ps.weights[mask].sum())


def mode_weight_below(ps: ParticleSet, radius: float, limit: float) -> bool:
    """Whether no disc of ``radius`` holds ``limit`` of the set's weight, by a bound (a
    grid of cells twice the radius), so certainly its main mode does not (True); False:
    it cannot tell (:func:`filter_mode` can)."""
    ox, oy = ps.origin_xy
    state = ps.state
    if not state.flags.c_contiguous:
        state = np.ascontiguousarray(state)
    return disc_weight_bound(state, ox, oy, ps.weights, float(radius)) < limit * (1.0 - SAFE)


def top_up_copies(
    particles: np.ndarray, weights: np.ndarray, cloud: np.ndarray,
    symmetries: Sequence[MapSymmetry], mass: float, radius: float,
    rng: np.random.Generator, grid: OccupancyGrid,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Each symmetric copy of ``cloud`` (the main mode's particles, world poses ``(M, 3)``)
    in turn, restricted to ``grid``'s free cells, topped up to ``mass`` of the weight of
    ``particles``, ``weights`` (:func:`~estimators.mcl.detection_consistency.widen`);
    returns the particles, weights and whether any copy got particles (the same as
    ``widen`` called copy after copy on ``symmetric_copies(cloud, s)[grid.is_free(...)]``
    and the particles and weights it returns)."""
    parts, w = particles, weights
    own = False  # whether ``parts`` is this function's copy yet
    cloud = np.ascontiguousarray(cloud, dtype=float)
    gx, gy = (float(v) for v in grid.origin)
    res = float(grid.resolution)
    occupied = grid.occupied
    radius = float(radius)
    placed = False
    x = y = None
    for sym in symmetries:
        a = float(sym.angle)
        cx, cy = (float(v) for v in sym.centre)
        turned = turned_free(cloud, cx, cy, a, math.cos(a), math.sin(a), gx, gy, res,
                             occupied)
        if not len(turned):
            continue
        # widen, copy by copy: the claims' centre, the weight near it, then the lightest
        # particles elsewhere turned into claims
        wn = w / w.sum()
        mx, my, exact, ok = uniform_centre(turned, radius)
        if ok:
            if x is None:
                x, y = parts[:, 0].copy(), parts[:, 1].copy()  # one compiled signature
            here, near, have, ok = copy_masks(x, y, wn, turned, mx, my, exact, radius)
        if not ok:  # a rounding-close case: numpy's order decides
            parts, w, k = widen(parts, w, turned, mass, radius, rng)
            own, x = True, None
            placed = placed or k > 0
            continue
        w = wn
        if have >= mass:
            continue
        k = min(max(1, int(round(mass * len(w)))), len(w) - int(here.sum()))
        if k < 1:
            continue
        slots = lightest_outside(wn, here, k)
        pool = turned[near] if near.any() else turned
        if not own:
            parts, own = np.array(parts, dtype=float), True
        parts[slots] = pool[rng.integers(0, len(pool), size=k)]
        x = y = None
        w = topped_up_weights(wn, here, slots, mass, have)
        placed = True
    return parts, w, placed


def load_kernels(grid: OccupancyGrid) -> None:
    """Load the compiled loops now (from numba's disk cache, compiling them the first
    time), with the argument types the passes above give them on ``grid``: otherwise the
    first step that keeps a copy pays it."""
    poses = np.zeros((2, 3))
    x = np.zeros(2)
    w = np.full(2, 0.5)
    here = np.zeros(2, dtype=np.bool_)
    mode_mask(np.zeros((3, 2), dtype=np.float32), 0.0, 0.0, w, 1.0)
    disc_weight_bound(np.zeros((3, 2), dtype=np.float32), 0.0, 0.0, w, 1.0)
    turned_free(poses, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, grid.occupied)
    uniform_centre(poses, 1.0)
    copy_masks(x, x, w, poses, 0.0, 0.0, False, 1.0)
    lightest_outside(w, here, 1)
    topped_up_weights(w, here, np.zeros(1, dtype=np.intp), 0.1, 0.0)
    weighted_median(x, w)
    x.flags.writeable = False  # as main_mode passes a filter's (read-only) positions
    weighted_median(x, w)
