"""Vectorized ray casting against circles and segments (numpy, no Python loop per ray)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RayScene:
    """Static geometry for ray casting.

    ``circle_*`` and ``segment_*`` arrays describe obstacles; ``*_mask`` holds
    one boolean column per sensor channel (0 = laser, 1 = sonar, 2 = camera /
    line of sight) saying whether that channel sees the shape.
    """

    circle_centers: np.ndarray  # (C, 2)
    circle_radii: np.ndarray  # (C,)
    circle_mask: np.ndarray  # (C, 3) bool
    seg_a: np.ndarray  # (S, 2)
    seg_b: np.ndarray  # (S, 2)
    seg_mask: np.ndarray  # (S, 3) bool


CHANNEL = {"laser": 0, "sonar": 1, "sight": 2}


def ray_circles(
    origins: np.ndarray, dirs: np.ndarray, centers: np.ndarray, radii: np.ndarray
) -> np.ndarray:
    """Distance along each ray to each circle, ``inf`` on a miss. Shape ``(R, C)``."""
    if len(centers) == 0:
        return np.full((len(origins), 0), np.inf)
    fx = origins[:, 0:1] - centers[:, 0]
    fy = origins[:, 1:2] - centers[:, 1]
    b = fx * dirs[:, 0:1] + fy * dirs[:, 1:2]
    disc = b * b - (fx * fx + fy * fy - radii * radii)
    sq = np.sqrt(np.maximum(disc, 0.0))
    t = -b - sq
    t = np.where(t < 0, -b + sq, t)  # origin inside the circle: exit point
    t[(disc < 0) | (t < 0)] = np.inf
    return t


def ray_segments(
    origins: np.ndarray, dirs: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray
) -> np.ndarray:
    """Distance along each ray to each segment, ``inf`` on a miss. Shape ``(R, S)``."""
    if len(seg_a) == 0:
        return np.full((len(origins), 0), np.inf)
    ex = seg_b[:, 0] - seg_a[:, 0]
    ey = seg_b[:, 1] - seg_a[:, 1]
    wx = seg_a[:, 0] - origins[:, 0:1]
    wy = seg_a[:, 1] - origins[:, 1:2]
    dx, dy = dirs[:, 0:1], dirs[:, 1:2]
    denom = dx * ey - dy * ex
    parallel = np.abs(denom) < 1e-12
    denom = np.where(parallel, 1.0, denom)
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    t[parallel | (t < 0) | (u < 0) | (u > 1)] = np.inf
    return t


def cast(
    scene: RayScene,
    origins: np.ndarray,
    dirs: np.ndarray,
    channel: int,
    extra_centers: np.ndarray | None = None,
    extra_radii: np.ndarray | None = None,
    extra_exclude: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of each ray on the scene plus optional extra circles (robots).

    Args:
        origins, dirs: ``(R, 2)`` ray origins and unit directions.
        channel: which sensor channel's visibility mask applies.
        extra_centers, extra_radii: dynamic circles (e.g. robots), ``(E, 2)``, ``(E,)``.
        extra_exclude: ``(R,)`` index of the extra circle each ray ignores
            (its own robot), or -1.

    Returns:
        ``(distance (R,), hit_extra (R,))``: the hit distance (``inf`` on a miss)
        and the index of the extra circle hit, or -1 when the nearest hit is static.
    """
    cm = scene.circle_mask[:, channel]
    centers, radii = scene.circle_centers[cm], scene.circle_radii[cm]
    n_static = len(radii)
    if extra_centers is not None and len(extra_centers):
        centers = np.concatenate([centers, extra_centers])
        radii = np.concatenate([radii, extra_radii])
    if len(radii):
        d = ray_circles(origins, dirs, centers, radii)
        if extra_exclude is not None and len(radii) > n_static:
            rows = np.nonzero(extra_exclude >= 0)[0]
            d[rows, n_static + extra_exclude[rows]] = np.inf
        j = d.argmin(1)
        best = d[np.arange(len(d)), j]
        hit_extra = np.where((j >= n_static) & np.isfinite(best), j - n_static, -1)
    else:
        best = np.full(len(origins), np.inf)
        hit_extra = np.full(len(origins), -1)
    sm = scene.seg_mask[:, channel]
    if sm.any():
        seg = ray_segments(origins, dirs, scene.seg_a[sm], scene.seg_b[sm]).min(1)
        hit_extra = np.where(seg < best, -1, hit_extra)
        best = np.minimum(best, seg)
    return best, hit_extra
