"""The per-step passes of the symmetric-copy keeper that run compiled.

:func:`filter_mode` is :func:`~estimators.mcl.detection_consistency.main_mode`'s mask
of a filter's particles and the weight in it, bit for bit
(``tests/estimators/mcl/test_copy_keeper.py``); :func:`mode_weight_below` settles by a
bound that no disc of the mode radius holds a given share of a set's weight, so a
spread-out belief needs neither its main mode nor its top mode and copies. The loops
are in :mod:`estimators.mcl._keeper_kernels`.
"""

from __future__ import annotations

import numpy as np

from estimators.mcl._keeper_kernels import SAFE, disc_weight_bound, mode_mask, weighted_median
from estimators.mcl.detection_consistency import main_mode
from estimators.mcl.modes import particle_modes
from estimators.mcl.team import ParticleSet

__all__ = ["filter_mode", "load_kernels", "mode_weight_below"]


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
    grid of cells twice the radius), so certainly no mode of that radius does (True);
    False: it cannot tell."""
    ox, oy = ps.origin_xy
    state = ps.state
    if not state.flags.c_contiguous:
        state = np.ascontiguousarray(state)
    return disc_weight_bound(state, ox, oy, ps.weights, float(radius)) < limit * (1.0 - SAFE)


def load_kernels() -> None:
    """Load the compiled loops now (from numba's disk cache, compiling them the first
    time), with the argument types the keeper gives them: otherwise the first step that
    keeps a copy pays it."""
    x = np.zeros(2)
    w = np.full(2, 0.5)
    mode_mask(np.zeros((3, 2), dtype=np.float32), 0.0, 0.0, w, 1.0)
    disc_weight_bound(np.zeros((3, 2), dtype=np.float32), 0.0, 0.0, w, 1.0)
    weighted_median(x, w)
    x.flags.writeable = False  # as main_mode passes a filter's (read-only) positions
    weighted_median(x, w)
    # the top mode (copy_weights.top_mode)
    particle_modes(np.zeros(6, dtype=np.float32), w, np.array([2], dtype=np.intp),
                   np.zeros((1, 2)), 1, 1.0, 1.0, (0.0, 0.0, 1.0, 1.0))
