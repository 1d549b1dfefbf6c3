"""Seeded smooth terrain: a height field with hills and steep (tip-over) patches."""

from __future__ import annotations

import numpy as np

from coop_loc_env._step_kernels import steep_candidates
from coop_loc_env.config import ScenarioConfig

_ALL = np.zeros(0, dtype=bool)  # "every point" for steep_candidates


class HeightField:
    """A height field on a regular grid covering the world.

    Heights are a sum of Gaussian hills (smooth, drivable) plus a few narrow
    steep patches whose slope exceeds the tip-over limit. Queries interpolate
    bilinearly and accept batches of points.

    Args:
        cfg: the scenario (size, resolution, amplitude, slopes).
        rng: generator that places the hills (seeded from ``layout_seed``).
    """

    def __init__(self, cfg: ScenarioConfig, rng: np.random.Generator) -> None:
        self.width, self.height = map(float, cfg.world_size)
        self.resolution = float(cfg.terrain_resolution)
        nx = int(np.ceil(self.width / self.resolution)) + 1
        ny = int(np.ceil(self.height / self.resolution)) + 1
        xs = np.linspace(0.0, self.width, nx)
        ys = np.linspace(0.0, self.height, ny)
        self.xs, self.ys = xs, ys
        self._lerp_tables: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # Constants of the per-step cell lookups (see _cells).
        self._inv_res = 1.0 / self.resolution
        self._f_max = np.array([nx - 1.000001, ny - 1.000001])
        # flat cell = (i, j) @ strides: one call, faster than multiply-add up to a few hundred
        # points (per-step queries hold one point per robot; large ones run once, at setup).
        self._strides = np.array([1, nx - 1], dtype=np.intp)
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        z = np.zeros_like(gx)
        for _ in range(cfg.terrain_hills):
            cx, cy = rng.uniform(0, self.width), rng.uniform(0, self.height)
            sigma = cfg.terrain_length_scale * rng.uniform(0.6, 1.4)
            amp = cfg.terrain_amplitude * rng.uniform(-1.0, 1.0)
            z += amp * np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * sigma**2))
        self.steep_centers = []
        tip = np.tan(np.deg2rad(cfg.tip_over_slope_deg))
        for _ in range(cfg.steep_patches):
            cx = rng.uniform(0.15, 0.85) * self.width
            cy = rng.uniform(0.15, 0.85) * self.height
            sigma = cfg.steep_patch_radius / 2.0
            # A Gaussian's maximum slope is amp / (sigma * sqrt(e)); make it 2x the limit.
            amp = 2.0 * tip * sigma * np.sqrt(np.e)
            z += amp * np.exp(-((gx - cx) ** 2 + (gy - cy) ** 2) / (2 * sigma**2))
            self.steep_centers.append((cx, cy))
        self.z = z  # (ny, nx), row = y
        dzdy, dzdx = np.gradient(z, self.resolution)
        self.dzdx, self.dzdy = dzdx, dzdy
        self.slope = np.arctan(np.hypot(dzdx, dzdy))
        self.tip_over_slope = np.deg2rad(cfg.tip_over_slope_deg)
        self.steep = self.slope > self.tip_over_slope
        # Cells whose steepest corner comes near the limit (a margin for rounding).
        self._steep_cells = self._corners(self.slope).max(axis=1) > self.tip_over_slope - 1e-9

    def _cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat cell index ``(k,)`` and position within the cell ``(k, 2)`` of ``points``."""
        f = np.asarray(points, dtype=float).reshape(-1, 2) * self._inv_res
        np.maximum(f, 0.0, out=f)
        np.minimum(f, self._f_max, out=f)
        cell = f.astype(np.intp)
        return cell @ self._strides, f - cell

    def _bilinear(
        self,
        grid: np.ndarray,
        points: np.ndarray,
        cells: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Bilinear interpolation of ``grid`` (row = y) at ``points (k, 2)``, clamped.

        ``cells`` is :meth:`_cells` of ``points`` when already known.
        """
        index, frac = self._cells(points) if cells is None else cells
        g = self._lerp_table(grid)[index]  # (k, 4)
        tx = frac[:, 0]
        low = g[:, 0] + tx * g[:, 1]
        high = g[:, 2] + tx * g[:, 3]
        return low + frac[:, 1] * (high - low)

    @staticmethod
    def _corners(grid: np.ndarray) -> np.ndarray:
        """``(cells, 4)`` table of each cell's corner values (00, 10, 01, 11)."""
        corners = np.stack([grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]], -1)
        return corners.reshape(-1, 4)

    def _lerp_table(self, grid: np.ndarray) -> np.ndarray:
        """``(cells, 4)`` table ``(z00, z10 - z00, z01, z11 - z01)`` per cell, cached per grid.

        The differences are those the interpolation along x takes, made once.
        """
        key = id(grid)
        table = self._lerp_tables.get(key)
        if table is None or table[0] is not grid:
            c = self._corners(grid)
            lerp = np.stack([c[:, 0], c[:, 1] - c[:, 0], c[:, 2], c[:, 3] - c[:, 2]], 1)
            table = (grid, lerp)
            self._lerp_tables[key] = table
        return table[1]

    def elevation(self, points: np.ndarray) -> np.ndarray:
        """Height at ``points (k, 2)``."""
        return self._bilinear(self.z, points)

    def gradient(self, points: np.ndarray) -> np.ndarray:
        """``(dz/dx, dz/dy)`` at ``points``, shape ``(k, 2)``."""
        return np.stack(self._slopes(points), 1)

    def _slopes(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``dz/dx`` and ``dz/dy`` at ``points``, each ``(k,)`` (cells looked up once)."""
        cells = self._cells(points)
        return self._bilinear(self.dzdx, points, cells), self._bilinear(self.dzdy, points, cells)

    def pitch_roll(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pitch (nose up positive) and roll of robots at ``poses (k, 3)``."""
        poses = np.asarray(poses, dtype=float).reshape(-1, 3)
        gx, gy = self._slopes(poses[:, :2])
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        along = gx * c + gy * s
        across = -gx * s + gy * c
        return np.arctan(along), np.arctan(across)

    def is_steep(self, points: np.ndarray, among: np.ndarray | None = None) -> np.ndarray:
        """Whether the slope at ``points`` exceeds the tip-over limit.

        With a boolean mask ``among`` only those points are tested (the others
        read False): a robot already tipped over on a slope costs nothing.
        """
        # The interpolated slope never exceeds its cell's steepest corner: most cells
        # can't be steep anywhere, and points in them need no interpolation.
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        maybe = np.empty(len(pts), dtype=bool)
        mask = _ALL if among is None else among
        if not steep_candidates(pts, self._inv_res, self._f_max, self._strides,
                                self._steep_cells, mask, maybe):
            return maybe  # (one compiled pass over the points: the usual case)
        cells = self._cells(points)
        maybe = self._steep_cells[cells[0]]
        if among is not None:
            maybe &= among
        if not np.count_nonzero(maybe):
            return maybe
        out = self._bilinear(self.slope, points, cells) > self.tip_over_slope
        if among is not None:
            out &= among
        return out
