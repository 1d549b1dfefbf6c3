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

from estimators.mcl._keeper_kernels import mode_mask, near_weight, turned_free
from estimators.mcl.detection_consistency import main_mode, widen
from estimators.mcl.map_symmetry import MapSymmetry
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.team import ParticleSet

__all__ = ["filter_mode", "top_up_copies"]


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
    cloud = np.ascontiguousarray(cloud, dtype=float)
    gx, gy = (float(v) for v in grid.origin)
    res = float(grid.resolution)
    occupied = grid.occupied
    placed = False
    for sym in symmetries:
        a = float(sym.angle)
        cx, cy = (float(v) for v in sym.centre)
        turned = turned_free(cloud, cx, cy, a, math.cos(a), math.sin(a), gx, gy, res,
                             occupied)
        if not len(turned):
            continue
        # widen's first steps: a copy that already holds ``mass`` is left as it is
        wn = w / w.sum()
        centre, _ = main_mode(turned[:, :2], np.full(len(turned), 1.0 / len(turned)), radius)
        if near_weight(parts[:, 0], parts[:, 1], wn, float(centre[0]), float(centre[1]),
                       float(radius)) >= mass:
            w = wn
            continue
        parts, w, k = widen(parts, w, turned, mass, radius, rng)
        placed = placed or k > 0
    return parts, w, placed
