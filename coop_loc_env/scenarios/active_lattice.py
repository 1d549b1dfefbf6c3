"""Active lattice: sonar robots localize globally in symmetric corridor lattices drawn per episode.

Every episode draws a corridor lattice (:mod:`coop_loc_env.scenarios.lattice_maps`):
``lattice_size x lattice_size`` junctions 5 m apart joined by 2.5 m corridors, some
corridors left out and dead-end spurs added, all symmetric under turns of order
``symmetry`` (2 or 4) about the centre; one widened corridor (the bay) breaks the
symmetry, and ``decoys`` widenings placed with their half-turn copies break only half
of it. The map is known to the robots (their MCL grids are built from it); four sonar
robots with MCL (as ``active_hallway``: up to 1000 particles each, detections transfer
beliefs) start ``"together"`` (within 3 m of a point) or ``"scattered"``.

Options (config fields of :class:`LatticeConfig`, set like any other key):
``lattice_size`` (default 5), ``symmetry`` (4), ``decoys`` (1), ``map_seed`` (``None``:
a new map every episode, drawn from the episode's seed; an integer fixes the map) and
``start`` (``"together"``; the start poses are drawn with the map, so ``start_poses`` is
not an option here). The world is ``FRAME`` = 40 m square for every lattice up
to 7 x 7 (larger ones grow it), the lattice centred and the rest solid, so the dict
observation's belief map (32 cells a side) has the same 1.25 m cells, and one policy
reads every size.

A reset builds the drawn map's world, sensors, MCL grids and observation tables
(cached per map, so a map drawn again costs nothing more); the figure is in
docs/learning.md (``scripts/bench/lattice_reset.py``).
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass
from typing import Any

import numpy as np

from coop_loc_env.config import ScenarioConfig
from coop_loc_env.scenarios import Scenario, register_scenario
from coop_loc_env.scenarios.fox import symmetric_hallway
from coop_loc_env.scenarios.lattice_maps import (
    LatticeMap,
    check_params,
    lattice_map,
    start_poses,
    world_edge,
)

#: Episodes last this many steps per junction along a side (0.5 s steps): 5 x 5 -> 300
#: steps (150 s), 7 x 7 -> 420 (210 s).
STEPS_PER_JUNCTION = 60


@dataclass(frozen=True)
class LatticeConfig(ScenarioConfig):
    """:class:`ScenarioConfig` with the lattice's options (module doc)."""

    lattice_size: int = 5
    symmetry: int = 4
    decoys: int = 1
    map_seed: int | None = None
    start: str = "together"

    def validate(self) -> None:
        """The lattice options, then every :class:`ScenarioConfig` check."""
        check_params(self.lattice_size, self.symmetry, self.decoys, self.map_seed, self.start)
        super().validate()

    def lattice(self, seed: int) -> LatticeMap:
        """The map of this family drawn from ``seed``."""
        return lattice_map(self.lattice_size, self.symmetry, self.decoys, seed)


class ActiveLattice(Scenario):
    """Four sonar robots localize globally in a symmetric corridor lattice drawn per episode."""

    def base_config(self) -> ScenarioConfig:
        hall = symmetric_hallway()
        fields = {f.name: getattr(hall, f.name) for f in dataclasses.fields(ScenarioConfig)}
        fields.update(name="active_lattice", n_robots=4, n_particles=1000, obstacles=(),
                      world_size=(world_edge(5), world_edge(5)))
        return LatticeConfig(**fields)

    def make_config(self, overrides: dict[str, Any]) -> ScenarioConfig:
        """The base config with ``overrides``; the world size, first map and horizon follow
        ``lattice_size`` and ``map_seed`` unless the overrides set them."""
        cfg = super().make_config(overrides)
        edge = world_edge(cfg.lattice_size)
        derived: dict[str, Any] = {}
        if "world_size" not in overrides:
            derived["world_size"] = (edge, edge)
        if "max_cycles" not in overrides:
            derived["max_cycles"] = STEPS_PER_JUNCTION * cfg.lattice_size
        first = cfg.lattice(cfg.map_seed or 0)
        if "obstacles" not in overrides:  # the map the env is built with (reset redraws it)
            derived["obstacles"] = first.obstacles
        # Start poses on that map: the env's reset then places the robots of the world it
        # holds without drawing from the episode's generator (every reset draws this
        # episode's map and start from it alike, whatever episodes came before).
        derived["start_poses"] = tuple(map(tuple, start_poses(
            first, cfg.n_robots, cfg.start, cfg.robot_radius, np.random.default_rng(0)
        ).tolist()))
        return cfg.replace(**derived)

    def reset_world(self, env, rng: np.random.Generator) -> None:
        """Draw this episode's map (from ``rng`` unless ``map_seed`` is set), rebuild what
        depends on it, and place the team."""
        cfg = env.config
        seed = cfg.map_seed if cfg.map_seed is not None else int(rng.integers(2**31 - 1))
        lmap = cfg.lattice(seed)
        poses = start_poses(lmap, cfg.n_robots, cfg.start, cfg.robot_radius, rng)
        install_map(env, lmap, poses, rng)
        env.lattice = lmap
        env.map_seed = seed


#: Per env, the parts built for its current map (kept while the env lives).
_PARTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def prepare_map_tables(cfg: ScenarioConfig, world) -> None:
    """Build the drawn map's MCL tables the fast way before the filters ask for them: its
    symmetries about the world's centre (the lattice's centre by construction) and its
    sonar range table (compiled, :mod:`estimators.mcl.range_cast`)."""
    from coop_loc_env.backends.mcl import SYMMETRY_OVERLAP, known_map, map_resolution
    from estimators.mcl.map_symmetry import seed_symmetries
    from estimators.mcl.range_cast import prepare_range_table

    if cfg.estimator != "mcl":
        return
    grid = known_map(world, "sonar", map_resolution(cfg))
    w, h = cfg.world_size
    seed_symmetries(grid, (w / 2, h / 2), SYMMETRY_OVERLAP)
    tuned = {**cfg.extras.get("mcl", {}), **cfg.extras.get("mcl_sonar", {})}
    cone = 0.5 * np.deg2rad(cfg.sonar_fov_deg) / cfg.sonar_beams
    prepare_range_table(grid, cfg.sonar_max_range, tuned.get("beam_lookup_bins") or 256, cone,
                        tuned.get("beam_rays_per_cone", 3))


def install_map(env, lmap: LatticeMap, poses: np.ndarray, rng: np.random.Generator) -> None:
    """Put ``lmap`` into ``env``: its world, sensors, estimators, mapper and observation
    builder (kept for the next reset on the same map; the per-map tables they read, such
    as the MCL grids and range tables, are cached per process), with the robots at
    ``poses``."""
    from coop_loc_env.backends.base import make_backends
    from coop_loc_env.camera import CameraPipeline
    from coop_loc_env.depth_from_motion import DepthFromMotion
    from coop_loc_env.mapping import TeamMapper
    from coop_loc_env.observations import ObservationBuilder
    from coop_loc_env.sensors import SensorSuite
    from coop_loc_env.world import World

    cfg = dataclasses.replace(env.config, obstacles=lmap.obstacles,
                              start_poses=tuple(map(tuple, poses.tolist())))
    parts = _PARTS.get(env)
    if parts is None or parts["map"] is not lmap:
        world = World(cfg)
        prepare_map_tables(cfg, world)
        backends = make_backends(cfg, world)
        old = env.observations
        parts = {
            "map": lmap,
            "world": world,
            "sensors": SensorSuite(cfg, world, camera_lists=False),
            "backends": backends,
            "mapper": TeamMapper(cfg, world),
            "observations": ObservationBuilder(cfg, old.belief_size,
                                               tuple(backends[0].feature_names), world),
        }
        _PARTS[env] = parts
    world = parts["world"]
    world.cfg = cfg
    world.reset(rng)
    env.config = cfg
    env.world = world
    env.sensors = parts["sensors"]
    env.backends = parts["backends"]
    env.mapper = parts["mapper"]
    env.observations = parts["observations"]
    env.depth = DepthFromMotion(cfg, len(world.layout.ooi_centers))
    env.camera = CameraPipeline(env.sensors, env.depth, world.layout.ooi_centers)


register_scenario("active_lattice", ActiveLattice())
