"""The belief as a map: observation blocks of ``obs_format="dict"``.

With ``obs_format="dict"`` an agent's observation is a Gymnasium ``Dict``:

* ``"vector"``: the flat observation (:mod:`coop_loc_env.observations`), then the
  ``belief_modes`` block (:class:`BeliefModesBlock`): the top ``belief_modes``
  modes of the robot's belief, heaviest first, 6 values each: weight, x/W*2-1,
  y/H*2-1, cos and sin heading, spread (m, the weighted RMS distance of the
  mode's particles from its mean); zero rows where fewer modes hold mass. A
  Gaussian belief (EKF, MLE) is one mode of weight 1, its spread
  ``sqrt(var_x + var_y)``.
* ``"belief_map"`` float32 ``(C, H, W)`` (:class:`BeliefMapBlock`), allocentric over
  the known map, ``H = W = belief_map_cells`` (row ``iy`` covers world ``y`` in
  ``[iy, iy + 1) * world_height / H``, column ``ix`` the same in ``x``):
  channels ``0 .. belief_map_headings - 1``: the robot's belief mass per cell and
  heading bin (bin ``k`` covers headings ``[-pi + k d, -pi + (k + 1) d)``,
  ``d = 2 pi / belief_map_headings``; the channels sum to the mass inside the
  grid, 1); then the known occupancy map (fraction of each cell occupied, as
  the robot's own range sensor sees the layout); then the teammates'
  communicated beliefs, position mass summed over the live teammates.

Both are observation blocks (:mod:`coop_loc_env.obs_blocks`), registered as
``belief_modes`` and ``belief_map``. Particle beliefs (MCL) are binned particle
by particle; Gaussian beliefs (EKF, MLE) are rasterized: the position density at
each cell centre times the cell area (normalized over the grid), times the
heading mass of each bin (the wrapped normal's), so one policy architecture
reads every estimator.
Everything comes from the beliefs and the known map (``world.layout``), never
from the true poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from gymnasium import spaces
from scipy.special import ndtr

from coop_loc_env.obs_blocks import OBS_LIMIT, ObsBlock, ObsInputs, ObsSetup
from estimators.mcl.batch import team_state, team_weights
from estimators.mcl.modes import MODE_FIELDS, particle_modes, raster_particles

MODE_RADIUS = 2.0  # m: a mode holds the particles within this of its seed ...
MODE_HEADING_TOL = math.pi / 4  # ... and within this of its heading (rad)
OCCUPANCY_SUPERSAMPLE = 4  # occupancy samples per belief-map cell edge


@dataclass
class TeamBeliefs:
    """Every robot's belief as the team shares it (what the blocks read).

    ``mean (n, 3)``, ``cov (n, 3, 3)``: every robot's belief mean and covariance;
    ``active (n,)``: the live robots; ``particles``: for each MCL backend, its robots'
    global indices and its filters (the particle sets).
    """

    mean: np.ndarray
    cov: np.ndarray
    active: np.ndarray
    particles: list[tuple[np.ndarray, list]]

    @classmethod
    def from_env(cls, env, active: np.ndarray | None = None) -> TeamBeliefs:
        """The beliefs of ``env``'s team: its shared estimates and its backends' particle
        filters; ``active`` defaults to the robots of ``env.agents``."""
        groups = []
        for backend in env.backends:
            filters = [backend.particle_filter(i) for i in range(len(backend.robots))]
            if filters and filters[0] is not None:
                groups.append((np.asarray(backend.robots), filters))
        if active is None:
            active = np.zeros(env.config.n_robots, dtype=bool)
            active[[env.agent_name_mapping[a] for a in env.agents]] = True
        return cls(env.estimated_poses, env.estimated_covariances, active, groups)

    def blocks(self):
        """``(robots, flat, w, ends, org)`` per particle group (block layout)."""
        for robots, filters in self.particles:
            flat, ends = team_state(filters)
            w = team_weights(filters)
            org = np.array([pf.state_origin for pf in filters]).reshape(-1, 2)
            yield robots, flat, w, ends, org


def team_beliefs(x: ObsInputs) -> TeamBeliefs:
    """The team's beliefs at this step (made once for every block that reads them)."""
    return x.shared("team_beliefs", lambda: TeamBeliefs.from_env(x.env, x.active))


def _check_int(name: str, value: object, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return value


class BeliefModesBlock(ObsBlock):
    """The ``belief_modes`` block of the dict observation's vector (module doc)."""

    name = "belief_modes"

    def __init__(self, cfg) -> None:
        self.k = _check_int("belief_modes", cfg.belief_modes, 1)
        self.world = tuple(float(v) for v in cfg.world_size)
        self.size = 6 * self.k
        self.names = [f"mode{m}_{f}" for m in range(self.k) for f in MODE_FIELDS]

    def space(self) -> spaces.Box:
        """``Box(-10, 10, (6 K,))`` (the vector's limits)."""
        return spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(self.size,), dtype=np.float32)

    def modes(self, beliefs: TeamBeliefs) -> np.ndarray:
        """``(n, K, 6)`` raw modes: weight, world x, y (m), cos, sin heading, spread (m)."""
        n = len(beliefs.mean)
        out = np.zeros((n, self.k, 6))
        gaussian = np.ones(n, dtype=bool)
        w, h = self.world
        for robots, flat, wt, ends, org in beliefs.blocks():
            out[robots] = particle_modes(flat, wt, ends, org, self.k, MODE_RADIUS,
                                         MODE_HEADING_TOL, (0.0, 0.0, w, h))
            gaussian[robots] = False
        if gaussian.any():
            m, c = beliefs.mean[gaussian], beliefs.cov[gaussian]
            out[gaussian, 0] = np.column_stack([
                np.ones(len(m)), m[:, 0], m[:, 1], np.cos(m[:, 2]), np.sin(m[:, 2]),
                np.sqrt(np.maximum(c[:, 0, 0] + c[:, 1, 1], 0.0))])
        return out

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        """Fill the block's columns ``out`` ``(n, 6 K)``."""
        out[:] = self.values(team_beliefs(x))

    def values(self, beliefs: TeamBeliefs) -> np.ndarray:
        """``(n, 6 K)`` float32 rows of the block (positions scaled to [-1, 1])."""
        raw = self.modes(beliefs)
        w, h = self.world
        present = raw[..., 0] > 0
        raw[..., 1] = np.where(present, raw[..., 1] * (2.0 / w) - 1.0, 0.0)
        raw[..., 2] = np.where(present, raw[..., 2] * (2.0 / h) - 1.0, 0.0)
        np.clip(raw, -10.0, 10.0, out=raw)
        return raw.reshape(len(raw), -1).astype(np.float32)


class BeliefMapBlock(ObsBlock):
    """The ``belief_map`` of the dict observation: ``(C, H, W)`` float32 (module doc).

    Args:
        cfg: the scenario (``belief_map_cells``, ``belief_map_headings``, ``world_size``).
        grids: each robot's known occupancy grid
            (:class:`~estimators.mcl.occupancy.OccupancyGrid`), one per robot.
    """

    name = "belief_map"
    entry = "belief_map"

    def __init__(self, cfg, grids: list) -> None:
        self.cells = _check_int("belief_map_cells", cfg.belief_map_cells, 2)
        self.headings = _check_int("belief_map_headings", cfg.belief_map_headings, 1)
        if len(grids) != cfg.n_robots:
            raise ValueError(f"need one grid per robot ({cfg.n_robots}), got {len(grids)}")
        self.n = cfg.n_robots
        self.world = tuple(float(v) for v in cfg.world_size)
        self.channels = self.headings + 2
        w, h = self.world
        self.cell_w, self.cell_h = w / self.cells, h / self.cells
        self.occupancy = np.stack([self._occupancy(g) for g in grids]).astype(np.float32)
        # cell centres (for rasterizing Gaussians)
        self._cx = (np.arange(self.cells) + 0.5) * self.cell_w
        self._cy = (np.arange(self.cells) + 0.5) * self.cell_h
        self._edges = -math.pi + np.arange(self.headings + 1) * (2 * math.pi / self.headings)

    def _occupancy(self, grid) -> np.ndarray:
        """``(H, W)`` fraction of each cell that ``grid`` marks occupied (sampled)."""
        s = OCCUPANCY_SUPERSAMPLE
        xs = (np.arange(self.cells * s) + 0.5) * self.cell_w / s
        ys = (np.arange(self.cells * s) + 0.5) * self.cell_h / s
        pts = np.stack(np.meshgrid(xs, ys), axis=-1)
        occ = ~grid.is_free(pts)
        return occ.reshape(self.cells, s, self.cells, s).mean(axis=(1, 3))

    def space(self) -> spaces.Box:
        """``Box(0, max(1, n - 1), (C, H, W), float32)``."""
        high = float(max(1, self.n - 1))
        return spaces.Box(0.0, high, shape=(self.channels, self.cells, self.cells),
                          dtype=np.float32)

    def belief_mass(self, beliefs: TeamBeliefs) -> np.ndarray:
        """``(n, headings, H, W)`` float32: every robot's belief mass per cell and bin."""
        out = np.zeros((self.n, self.headings, self.cells, self.cells), dtype=np.float32)
        gaussian = np.ones(self.n, dtype=bool)
        for robots, flat, wt, ends, org in beliefs.blocks():
            out[robots] = raster_particles(flat, wt, ends, org, 0.0, 0.0, self.cell_w,
                                           self.cell_h, self.cells, self.cells, self.headings)
            gaussian[robots] = False
        for i in np.flatnonzero(gaussian).tolist():
            out[i] = self._gaussian(beliefs.mean[i], beliefs.cov[i])
        return out

    def _gaussian(self, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
        """``(headings, H, W)``: a Gaussian pose belief's mass per cell and heading bin."""
        floor = (0.25 * min(self.cell_w, self.cell_h)) ** 2  # a point mass still fills a cell
        c = cov[:2, :2] + floor * np.eye(2)
        inv = np.linalg.inv(c)
        dx = self._cx[None, :] - mean[0]
        dy = self._cy[:, None] - mean[1]
        q = inv[0, 0] * dx**2 + 2 * inv[0, 1] * dx * dy + inv[1, 1] * dy**2
        pos = np.exp(-0.5 * q)
        total = pos.sum()
        pos = pos / total if total > 0 else pos
        sd = math.sqrt(max(cov[2, 2], 1e-6))
        mu = (mean[2] + math.pi) % (2 * math.pi) - math.pi
        mass = np.zeros(self.headings)
        for shift in (-2 * math.pi, 0.0, 2 * math.pi):  # the wrapped normal
            mass += np.diff(ndtr((self._edges - mu - shift) / sd))
        mass /= max(mass.sum(), 1e-12)
        return mass[:, None, None] * pos[None]

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        """Fill ``out`` ``(n, C, H, W)`` with every robot's map."""
        self.values(team_beliefs(x), out)

    def values(self, beliefs: TeamBeliefs, out: np.ndarray | None = None) -> np.ndarray:
        """``(n, C, H, W)`` float32 maps of every robot (into ``out`` if given)."""
        if out is None:
            out = np.empty((self.n, self.channels, self.cells, self.cells), dtype=np.float32)
        mass = self.belief_mass(beliefs)
        out[:, : self.headings] = mass
        out[:, self.headings] = self.occupancy
        position = mass.sum(axis=1)
        position[~np.asarray(beliefs.active, dtype=bool)] = 0.0  # live robots only
        team = position.sum(axis=0)  # every live robot's mass ...
        np.subtract(team[None], position, out=out[:, -1])  # ... less the own
        np.clip(out[:, -1], 0.0, self.n - 1, out=out[:, -1])  # float rounding
        return out


def modes_block(setup: ObsSetup) -> BeliefModesBlock:
    """The registered ``belief_modes`` block of ``setup``'s config."""
    return BeliefModesBlock(setup.cfg)


def map_block(setup: ObsSetup) -> BeliefMapBlock:
    """The registered ``belief_map`` block: each robot's known map from ``setup.world``."""
    return BeliefMapBlock(setup.cfg, robot_grids(setup.cfg, setup.world))


def robot_grids(cfg, world) -> list:
    """Each robot's known occupancy grid: the layout as its own range sensor sees it."""
    from coop_loc_env.backends.mcl import known_map, map_resolution

    res = map_resolution(cfg)
    kinds = [cfg.robot_spec(i).range_sensor for i in range(cfg.n_robots)]
    cache = {k: known_map(world, k, res) for k in set(kinds)}
    return [cache[k] for k in kinds]
