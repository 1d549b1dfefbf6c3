"""Rotational self-similarities of a known map, and the symmetric copies of a pose they imply.

A robot alone in a map that looks the same under a turn about some centre cannot
tell its pose from the turned copies until it sees a feature that breaks the
symmetry; its posterior keeps every copy. A particle filter with a bounded
particle budget does not: while the robot's scans are still ambiguous along
whole corridors, the particles cover the copies sparsely, and whichever copies
happen to hold particles when the ambiguity narrows down survive; the filter
then reports one copy, sharply, and is confidently wrong about as often as the
map has copies. The map tells which copies its sensors cannot tell apart, so
they can be kept.

:func:`map_symmetries` finds the turns (by ``360 / n`` degrees, ``n`` in
:data:`FOLDS`) that map the grid's free space onto itself up to a share
``min_overlap`` of it (a bay that breaks the symmetry is a small share), each
about the centre that overlaps best (searched around the free space's centroid,
then refined), cached on the grid. :func:`symmetric_copies` applies them to poses.
Whether a robot's own scans tell a copy apart is for the caller to weigh (the MCL
backend scores its recent scans along its odometry at both, with
:func:`estimators.mcl.detection_consistency.scan_loglik_along`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl.occupancy import OccupancyGrid

__all__ = ["FOLDS", "MapSymmetry", "map_symmetries", "symmetric_copies"]

FOLDS = (2, 3, 4, 6, 8)  # turns by 360 / n degrees (and their multiples) are tried
CENTRE_SEARCH_M = 1.5  # m around the free space's centroid searched for each turn's centre


class MapSymmetry(NamedTuple):
    """A turn by ``angle`` (rad) about ``centre`` (world x, y) under which a share
    ``overlap`` of the map's free space lands on free space."""

    angle: float
    centre: tuple[float, float]
    overlap: float


def _lookup(mask: np.ndarray, grid: OccupancyGrid, xy: np.ndarray) -> np.ndarray:
    """``mask`` (the grid's shape) at world points ``xy``; False off the grid."""
    c = grid.world_to_cell(xy)
    ny, nx = mask.shape
    inside = (c[:, 0] >= 0) & (c[:, 0] < nx) & (c[:, 1] >= 0) & (c[:, 1] < ny)
    out = np.zeros(len(xy), dtype=bool)
    out[inside] = mask[c[inside, 1], c[inside, 0]]
    return out


def _overlap(points: np.ndarray, target: np.ndarray, grid: OccupancyGrid, angle: float,
             centre: np.ndarray) -> float:
    c, s = math.cos(angle), math.sin(angle)
    d = points - centre
    turned = np.column_stack([centre[0] + c * d[:, 0] - s * d[:, 1],
                              centre[1] + s * d[:, 0] + c * d[:, 1]])
    return float(_lookup(target, grid, turned).mean())


def _best_centre(points: np.ndarray, targets: tuple[np.ndarray, np.ndarray],
                 grid: OccupancyGrid, angle: float, start: np.ndarray) -> tuple[np.ndarray, float]:
    """The centre (searched on a grid of cell steps around ``start`` landing ``points`` on
    the coarse target, then of quarter cells around the best on the exact one; ties resolved
    by their mean) under which the turn by ``angle`` lands most ``points`` on ``targets``;
    and the share it lands on the coarse target."""
    best = start
    ovs_coarse = 0.0
    for target, step, reach in ((targets[0], grid.resolution, CENTRE_SEARCH_M),
                                (targets[1], 0.25 * grid.resolution, grid.resolution)):
        k = int(round(reach / step))
        offsets = step * np.array([(dx, dy) for dx in range(-k, k + 1)
                                   for dy in range(-k, k + 1)])
        centres = best + offsets
        ovs = np.array([_overlap(points, target, grid, angle, c) for c in centres])
        top = ovs >= ovs.max() - 1e-12
        best = centres[top].mean(axis=0)
        if target is targets[0]:
            ovs_coarse = float(ovs.max())
    # a layout symmetric about a cell corner or centre rasterizes symmetric about it: the
    # nearest such point when it does as well (the ties' mean can sit a little off it)
    half = 0.5 * grid.resolution
    org = np.asarray(grid.origin, dtype=float)
    snapped = org + half * np.round((best - org) / half)
    if _overlap(points, targets[1], grid, angle, snapped) >= float(ovs.max()) - 1e-12:
        best = snapped
    return best, _overlap(points, targets[0], grid, angle, best) if ovs_coarse else 0.0


def _surface(grid: OccupancyGrid) -> np.ndarray:
    """Free cells next to an occupied one (4-neighbours): where a range sensor sees walls."""
    occ = np.pad(grid.occupied, 1, constant_values=True)
    near = occ[:-2, 1:-1] | occ[2:, 1:-1] | occ[1:-1, :-2] | occ[1:-1, 2:]
    return ~grid.occupied & near


def _surface_points_and_target(grid: OccupancyGrid) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """The wall surface's cell centres (world frame), the target they are scored
    against (the surface one cell thicker: a turned cell centre rarely lands on one)
    and the surface itself."""
    surface = _surface(grid)
    iy, ix = np.nonzero(surface)
    points = grid.cell_to_world(np.column_stack([ix, iy]))
    pad = np.pad(surface, 1)
    target = (pad[1:-1, 1:-1] | pad[:-2, 1:-1] | pad[2:, 1:-1] | pad[1:-1, :-2]
              | pad[1:-1, 2:]) & ~grid.occupied
    return points, target, surface


def _turn_fractions() -> list[float]:
    """The turns of :data:`FOLDS` as fractions of a full turn, identity excluded."""
    return sorted({k / n for n in FOLDS for k in range(1, n)})


def _find(grid: OccupancyGrid, min_overlap: float) -> tuple[MapSymmetry, ...]:
    points, target, surface = _surface_points_and_target(grid)
    if len(points) == 0:
        return ()
    iy, ix = np.nonzero(~grid.occupied)
    centroid = grid.cell_to_world(np.column_stack([ix, iy])).mean(axis=0)
    found = []
    for frac in _turn_fractions():
        angle = 2 * math.pi * frac
        centre, ov = _best_centre(points, (target, surface), grid, angle, centroid)
        if ov >= min_overlap:
            found.append(MapSymmetry(float(wrap_angle(angle)), (float(centre[0]),
                                                                float(centre[1])), ov))
    return tuple(found)


def map_symmetries(grid: OccupancyGrid, min_overlap: float = 0.8) -> tuple[MapSymmetry, ...]:
    """The turns of :data:`FOLDS` under which at least ``min_overlap`` of ``grid``'s wall
    surface (free cells next to occupied ones) lands within a cell of wall surface (the
    identity excluded), each about its best centre (module doc); cached on the grid."""
    if not 0.0 < min_overlap <= 1.0:
        raise ValueError(f"min_overlap must be in (0, 1], got {min_overlap}")
    if not isinstance(grid, OccupancyGrid):
        raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    return grid.memo(("map_symmetries", float(min_overlap)), lambda: _find(grid, min_overlap))


def symmetric_copies(poses: np.ndarray, symmetry: MapSymmetry) -> np.ndarray:
    """``poses`` ``(N, 3)`` (or one ``(3,)``) turned by ``symmetry``: positions about its
    centre, headings by its angle (wrapped)."""
    poses = np.asarray(poses, dtype=float)
    one = poses.ndim == 1
    p = poses.reshape(-1, 3)
    c, s = math.cos(symmetry.angle), math.sin(symmetry.angle)
    cx, cy = symmetry.centre
    dx, dy = p[:, 0] - cx, p[:, 1] - cy
    out = np.column_stack([cx + c * dx - s * dy, cy + s * dx + c * dy,
                           wrap_angle(p[:, 2] + symmetry.angle)])
    return out[0] if one else out


def seed_symmetries(grid: OccupancyGrid, centre: tuple[float, float],
                    min_overlap: float = 0.8) -> tuple[MapSymmetry, ...]:
    """:func:`map_symmetries` of a map whose generator knows its centre of symmetry: the
    same turns scored about ``centre`` only (no search, milliseconds instead of a
    fraction of a second), cached on the grid as ``map_symmetries(grid, min_overlap)``'s
    answer."""
    if not 0.0 < min_overlap <= 1.0:
        raise ValueError(f"min_overlap must be in (0, 1], got {min_overlap}")

    def find() -> tuple[MapSymmetry, ...]:
        points, target, _ = _surface_points_and_target(grid)
        if len(points) == 0:
            return ()
        c = np.asarray(centre, dtype=float)
        found = []
        for frac in _turn_fractions():
            angle = 2 * math.pi * frac
            ov = _overlap(points, target, grid, angle, c)
            if ov >= min_overlap:
                found.append(MapSymmetry(float(wrap_angle(angle)),
                                         (float(c[0]), float(c[1])), ov))
        return tuple(found)

    return grid.memo(("map_symmetries", float(min_overlap)), find)
