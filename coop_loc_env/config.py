"""Scenario configuration as plain data.

A :class:`ScenarioConfig` holds every parameter of an episode: world, terrain,
obstacles, the team (one :class:`RobotSpec` pattern cycled over the robots so
teams can be heterogeneous), sensor rates and noise, rewards and episode
length. Named scenarios build one (see :mod:`coop_loc_env.scenarios`), and
every field can be overridden by keyword; :meth:`ScenarioConfig.validate`
rejects bad values with a ``ValueError`` that names the key and the value.

Units: metres, seconds, radians (fields ending in ``_deg`` are degrees).
Default rates and noise follow Table 1 of the outdoor paper (Madhavan et al.).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from coop_loc_env.backends import BUILTIN_ESTIMATORS, check_estimator, validate_extras
from coop_loc_env.obs_blocks import check_obs_blocks
from coop_loc_env.rewards import check_reward_config

#: The estimators shipped with the package; every name registered with
#: :func:`coop_loc_env.backends.register_backend` is accepted.
ESTIMATORS = BUILTIN_ESTIMATORS
DETECTION_MODELS = ("fox", "howard", "laser", "camera", "scan_min")
OBSTACLE_KINDS = ("tree", "rock", "wall", "ooi", "building")
OBSTACLE_SHAPES = ("circle", "segment", "polygon")
RANGE_SENSOR_TYPES = ("laser", "sonar")
OBS_FORMATS = ("flat", "dict")
#: Largest team the env simulates (sensing is pairwise: at this size on an 80 m field a
#: step takes ~0.2 s and the random start placement ~10 s).
MAX_ROBOTS = 1000
#: Gap (m) the random start placement keeps between two robots' edges (see ``World``).
START_GAP = 0.3


#: The checks a field's ``metadata["bound"]`` asks for (see :func:`_number`).
_BOUNDS: dict[str, dict[str, Any]] = {
    "positive": {"lower": 0.0, "strict": True},
    "non_negative": {"lower": 0.0, "strict": False},
    "probability": {"lower": 0.0, "strict": False, "upper": 1.0},
}


def _positive(default: float) -> Any:
    """A float field that :meth:`ScenarioConfig.validate` requires finite and > 0."""
    return field(default=default, metadata={"bound": "positive"})


def _non_negative(default: float) -> Any:
    """A float field that :meth:`ScenarioConfig.validate` requires finite and >= 0."""
    return field(default=default, metadata={"bound": "non_negative"})


def _probability(default: float) -> Any:
    """A float field that :meth:`ScenarioConfig.validate` requires in [0, 1]."""
    return field(default=default, metadata={"bound": "probability"})


@dataclass(frozen=True)
class Obstacle:
    """A static obstacle.

    Args:
        kind: ``"tree"``, ``"rock"``, ``"wall"``, ``"building"`` or ``"ooi"``
            (object of interest: a landmark the camera looks for).
        shape: ``"circle"`` (``center``, ``radius``), ``"segment"`` (``a``, ``b``,
            ``radius`` = half thickness) or ``"polygon"`` (``vertices``).
        canopy_radius: for trees, radius of the canopy that blocks GPS.
        visible_to: which range sensor types see it (``"laser"``, ``"sonar"``);
            lets a scenario hold features that only one sensor type perceives.
        solid: whether robots collide with it.
    """

    kind: str
    shape: str
    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.5
    a: tuple[float, float] = (0.0, 0.0)
    b: tuple[float, float] = (0.0, 0.0)
    vertices: tuple[tuple[float, float], ...] = ()
    canopy_radius: float = 0.0
    visible_to: tuple[str, ...] = RANGE_SENSOR_TYPES
    solid: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` on an unknown kind/shape or a bad size."""
        if self.kind not in OBSTACLE_KINDS:
            raise ValueError(f"obstacle kind must be one of {OBSTACLE_KINDS}, got {self.kind!r}")
        if self.shape not in OBSTACLE_SHAPES:
            raise ValueError(
                f"obstacle shape must be one of {OBSTACLE_SHAPES}, got {self.shape!r}"
            )
        if not self.radius > 0 and self.shape != "polygon":
            raise ValueError(f"obstacle radius must be > 0, got {self.radius!r}")
        if self.shape == "polygon" and len(self.vertices) < 3:
            raise ValueError(f"polygon obstacle needs >= 3 vertices, got {self.vertices!r}")
        for t in self.visible_to:
            if t not in RANGE_SENSOR_TYPES:
                raise ValueError(f"visible_to entries must be in {RANGE_SENSOR_TYPES}, got {t!r}")


@dataclass(frozen=True)
class RobotSpec:
    """One robot's hardware and estimator; a team cycles a tuple of these.

    Sensor flags switch sensors on; ``range_sensor`` picks ``"laser"`` (many
    narrow beams) or ``"sonar"`` (few wide cones, noisier) for the range finder.
    Fields left ``None`` take the scenario-wide value.
    """

    estimator: str | None = None
    has_gps: bool = True
    has_compass: bool = True
    has_inclinometer: bool = True
    has_range_sensor: bool = True
    range_sensor: str = "laser"
    has_camera: bool = True
    has_detector: bool = True
    max_speed: float | None = None
    max_turn_rate: float | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` on an unregistered estimator or an unknown sensor type."""
        if self.estimator is not None:
            check_estimator("estimator", self.estimator)
        if self.range_sensor not in RANGE_SENSOR_TYPES:
            raise ValueError(
                f"range_sensor must be one of {RANGE_SENSOR_TYPES}, got {self.range_sensor!r}"
            )
        for key in ("max_speed", "max_turn_rate"):
            value = getattr(self, key)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be a positive number, got {value!r}")


@dataclass(frozen=True)
class ScenarioConfig:
    """Every parameter of a scenario. See the module docstring for units."""

    name: str = "custom"
    # --- team and episode
    n_robots: int = 3
    team: tuple[RobotSpec, ...] = (RobotSpec(),)
    estimator: str = "ekf"
    max_cycles: int = 500
    dt: float = _positive(0.1)
    privileged_obs: bool = False
    # --- world and layout (layout_seed fixes the map across episodes)
    world_size: tuple[float, float] = (40.0, 40.0)
    layout_seed: int = 0
    obstacles: tuple[Obstacle, ...] = ()
    n_random_trees: int = 0
    n_random_rocks: int = 0
    n_random_ooi: int = 0
    tree_radius: float = _positive(0.4)
    canopy_radius: float = _non_negative(3.0)
    rock_radius: float = _positive(0.8)
    start_region: tuple[float, float, float, float] | None = None
    start_poses: tuple[tuple[float, float, float], ...] | None = None
    # --- terrain
    terrain_amplitude: float = _non_negative(1.5)
    terrain_length_scale: float = _positive(6.0)
    terrain_hills: int = 8
    terrain_resolution: float = _positive(0.5)
    steep_patches: int = 2
    steep_patch_radius: float = _positive(2.0)
    tip_over_slope_deg: float = _positive(30.0)
    tip_over_terminates: bool = True
    # --- robot motion
    max_speed: float = _positive(1.0)
    max_turn_rate: float = _positive(1.0)
    robot_radius: float = _positive(0.35)
    slip_std: float = _non_negative(0.03)
    # --- odometry (Table 1: ~50 Hz)
    odometry_rate: float = _positive(50.0)
    odom_v_std: float = _non_negative(0.05)
    odom_w_std: float = _non_negative(0.05)
    # --- DGPS (~1 Hz); variance = gps_std**2 * gps_reference_satellites / NOS
    gps_rate: float = _positive(1.0)
    gps_std: float = _non_negative(0.3)
    gps_reference_satellites: int = 8
    gps_open_sky_satellites: tuple[int, int] = (7, 12)
    gps_canopy_satellites: tuple[int, int] = (0, 3)
    gps_multipath_prob: float = _probability(0.02)
    gps_multipath_std: float = _non_negative(5.0)
    gps_base_altitude: float = 0.0
    gps_altitude_std: float = _non_negative(0.5)
    # --- compass and inclinometer (~1 Hz)
    compass_rate: float = _positive(1.0)
    compass_std: float = _non_negative(0.05)
    inclinometer_rate: float = _positive(1.0)
    inclinometer_std: float = _non_negative(0.01)
    # --- range finder (~10 Hz)
    laser_rate: float = _positive(10.0)
    laser_beams: int = 30
    laser_fov_deg: float = _positive(180.0)
    laser_max_range: float = _positive(15.0)
    laser_range_std: float = _non_negative(0.03)
    sonar_beams: int = 8
    sonar_fov_deg: float = _positive(360.0)
    sonar_max_range: float = _positive(6.0)
    sonar_range_std: float = _non_negative(0.15)
    # --- camera (~10 Hz): 160 px over 37 deg -> 0.231 deg/px
    camera_rate: float = _positive(10.0)
    camera_fov_deg: float = _positive(37.0)
    camera_width_px: int = 160
    camera_max_range: float = _positive(20.0)
    # range std of a fresh track (depth from motion refines it)
    camera_range_std: float = _non_negative(1.0)
    # optical-flow bearing noise for depth from motion (pixels)
    camera_flow_std_px: float = _non_negative(0.5)
    # weight of motion along the line of sight in the baseline
    camera_looming_gain: float = _non_negative(0.3)
    # --- robot detector (identity + range, bearing, orientation)
    detector_rate: float = _positive(2.0)
    detector_range: float = _positive(8.0)
    detector_fov_deg: float = _positive(360.0)
    detection_model: str = "fox"
    detection_prob: float = _probability(0.933)
    false_positive_prob: float = _probability(0.035)
    detection_range_std: float = _non_negative(0.3)
    detection_bearing_std: float = _non_negative(0.04)
    detection_orientation_std: float = _non_negative(0.1)
    detection_range_fraction: float = _non_negative(0.05)
    # False: range and bearing only (the orientation reads 0 with a huge variance)
    detection_orientation: bool = True
    cooperative_updates: bool = True
    cooperative_fusion: str = "ci"
    cooperative_rounds_per_step: int = 1
    # --- estimators
    gate_prob: float = 0.99
    ekf_process_noise_scale: float = _positive(1.0)
    init_pos_std: float = _non_negative(0.5)
    init_heading_std: float = _non_negative(0.1)
    n_particles: int = 1000  # MCL: maximum particles per robot (KLD-sampling adapts below it)
    global_localization: bool = False  # MCL: start particles uniform over free space
    # --- observations
    laser_obs_bins: int = 16
    max_detections_obs: int = 3
    map_patch_obs: int = 0  # egocentric terrain-map patch edge in cells (0 = off)
    teammate_obs: bool = False  # nearest GPS / no-GPS teammates' shared estimates in the obs
    # "flat" (one vector) or "dict": the vector plus the belief's modes, and the belief as a
    # map (coop_loc_env.belief_map)
    obs_format: str = "flat"
    belief_map_cells: int = 32  # dict observation: belief-map cells a side
    belief_map_headings: int = 8  # dict observation: heading bins of the belief map
    belief_modes: int = 4  # dict observation: modes of the belief in the vector
    # registered observation blocks (coop_loc_env.obs_blocks) appended to the vector
    extra_obs_blocks: tuple[str, ...] = ()
    # --- team terrain map (coop_loc_env.mapping)
    map_resolution: float = _positive(0.5)
    map_footprint_radius: float = _non_negative(0.5)
    map_fusion_weights: str = "paper"  # "paper" (satellite-count weights) or "kalman"
    # --- reward weights
    reward_localization_weight: float = _non_negative(1.0)
    reward_heading_weight: float = _non_negative(0.0)
    reward_coverage_weight: float = _non_negative(0.0)
    reward_team_weight: float = _non_negative(0.0)  # times minus the team's mean position error
    # times minus the change of own 0.5 log det P_xy
    reward_uncertainty_weight: float = _non_negative(0.0)
    collision_penalty: float = _non_negative(0.1)
    tip_over_penalty: float = _non_negative(10.0)
    # registered reward terms (coop_loc_env.rewards) added after the built-in ones, each
    # with its default weight unless reward_weights names it (which also adds it)
    extra_reward_terms: tuple[str, ...] = ()
    reward_weights: dict[str, float] = field(default_factory=dict)
    # --- infos: every value is a number or a fixed-shape array (TorchRL, BenchMARL stack them);
    # True adds the dict ``reward_terms`` beside the ``reward_<term>`` keys (always there)
    reward_terms_dict: bool = False
    # the info keys to keep (None: all); an unknown key raises ValueError at the first step
    info_keys: tuple[str, ...] | None = None
    # --- estimator options read by one backend; every key is declared (and checked) by
    # the backend that reads it (coop_loc_env.backends, coop_loc_env.extras)
    extras: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ helpers
    def robot_spec(self, i: int) -> RobotSpec:
        """Robot ``i``'s spec (the team pattern cycled), with defaults resolved."""
        spec = self.team[i % len(self.team)]
        return dataclasses.replace(
            spec,
            estimator=spec.estimator or self.estimator,
            max_speed=spec.max_speed or self.max_speed,
            max_turn_rate=spec.max_turn_rate or self.max_turn_rate,
        )

    @property
    def estimators(self) -> tuple[str, ...]:
        """The estimator each robot runs (``RobotSpec.estimator``, else :attr:`estimator`)."""
        return tuple(self.robot_spec(i).estimator for i in range(self.n_robots))

    def replace(self, **overrides: Any) -> ScenarioConfig:
        """A validated copy with ``overrides``; unknown keys raise ``ValueError``.

        ``estimator=`` sets every robot's estimator: it clears the per-robot
        ``RobotSpec.estimator`` of the team unless ``team=`` is given too.
        """
        known = {f.name for f in dataclasses.fields(self)}
        for key in overrides:
            if key not in known:
                raise ValueError(
                    f"unknown config key {key!r} for scenario {self.name!r}; "
                    f"known keys: {', '.join(sorted(known))}"
                )
        for key in ("team", "obstacles", "world_size", "start_region", "start_poses", "info_keys",
                    "extra_obs_blocks", "extra_reward_terms"):
            if key in overrides and isinstance(overrides[key], list):
                overrides[key] = tuple(overrides[key])
        if "team" in overrides:
            overrides["team"] = _team_specs(overrides["team"])
        if "estimator" in overrides and "team" not in overrides:
            # An explicit estimator= overrides the per-robot estimators of this config's team
            # (a team passed alongside it keeps its own: estimator= is then their default).
            overrides["team"] = tuple(
                dataclasses.replace(s, estimator=None) if isinstance(s, RobotSpec) else s
                for s in self.team
            )
        cfg = dataclasses.replace(self, **overrides)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        """Check every field; raise ``ValueError`` naming the key and value."""
        for check in _CHECKS:
            check(self)

    def start_capacity(self) -> int:
        """An upper bound on how many robots random start placement can fit.

        Robot centres keep ``robot_radius`` from the start region's edges and
        ``2 robot_radius + START_GAP`` from each other, so disks of half that
        spacing around them are disjoint and lie in the region grown by half the
        spacing: no more than its area over one disk's area fit.
        """
        w, h = self.world_size
        x0, y0, x1, y1 = self.start_region or (1.0, 1.0, w - 1.0, h - 1.0)
        r = self.robot_radius
        spacing = 2 * r + START_GAP
        width = max(x1 - x0 - 2 * r, 0.0) + spacing
        height = max(y1 - y0 - 2 * r, 0.0) + spacing
        return int(width * height / (math.pi * spacing**2 / 4))

    def check_team_size(self) -> None:
        """Refuse teams too large to simulate or to place (before anything is built)."""
        if self.n_robots > MAX_ROBOTS:
            raise ValueError(
                f"n_robots must be <= {MAX_ROBOTS} (the largest team simulated), "
                f"got {self.n_robots!r}"
            )
        if self.start_poses is None:
            capacity = self.start_capacity()
            if self.n_robots > capacity:
                region = self.start_region or "the world"
                raise ValueError(
                    f"n_robots={self.n_robots} robots of radius {self.robot_radius:g} m cannot "
                    f"be placed in start_region {region}: at most {capacity} fit; use fewer "
                    "robots, a larger start_region, or start_poses"
                )

    @functools.cached_property
    def odometry_substeps(self) -> int:
        """Physics/odometry substeps per env step (computed once: the config is frozen)."""
        return max(1, int(round(self.dt * self.odometry_rate)))


#: Integer fields and their least value, checked in this order.
_COUNTS = (
    ("n_robots", 1), ("max_cycles", 1), ("laser_beams", 1), ("sonar_beams", 1),
    ("camera_width_px", 1), ("laser_obs_bins", 1), ("max_detections_obs", 0),
    ("map_patch_obs", 0), ("n_particles", 10), ("belief_map_cells", 2),
    ("belief_map_headings", 1), ("belief_modes", 1), ("gps_reference_satellites", 1),
    ("n_random_trees", 0), ("n_random_rocks", 0), ("n_random_ooi", 0), ("terrain_hills", 0),
    ("steep_patches", 0), ("cooperative_rounds_per_step", 1),
)
#: Fields that name one of a few choices: (field, choices, how the error words them).
_CHOICES = (
    ("obs_format", OBS_FORMATS, f"one of {OBS_FORMATS}"),
    ("map_fusion_weights", ("paper", "kalman"), "'paper' or 'kalman'"),
    ("cooperative_fusion", ("ci", "naive"), "'ci' or 'naive'"),
    ("detection_model", DETECTION_MODELS, f"one of {DETECTION_MODELS}"),
)


def _check_counts(cfg: ScenarioConfig) -> None:
    for key, low in _COUNTS:
        _int_at_least(cfg, key, low)


def _check_choices(cfg: ScenarioConfig) -> None:
    for key, choices, wanted in _CHOICES:
        value = getattr(cfg, key)
        if value not in choices:
            raise ValueError(f"{key} must be {wanted}, got {value!r}")


def _check_flags(cfg: ScenarioConfig) -> None:
    """Every ``bool`` field (a string such as ``"false"`` from a command line is truthy)."""
    for f in dataclasses.fields(cfg):
        value = getattr(cfg, f.name)
        if f.type in ("bool", bool) and not isinstance(value, bool):
            raise ValueError(f"{f.name} must be True or False, got {value!r}")


def _check_info_keys(cfg: ScenarioConfig) -> None:
    keys = cfg.info_keys
    if keys is not None and (not isinstance(keys, tuple)
                             or not all(isinstance(k, str) for k in keys)):
        raise ValueError(f"info_keys must be None or a list of key names, got {keys!r}")


def _check_numbers(cfg: ScenarioConfig) -> None:
    for f in dataclasses.fields(cfg):  # the bounds declared beside the fields
        bound = f.metadata.get("bound")
        if bound is not None:
            _number(cfg, f.name, **_BOUNDS[bound])
    _number(cfg, "gate_prob", lower=0.0, strict=True, upper=1.0)
    if cfg.tip_over_slope_deg >= 90:
        raise ValueError(f"tip_over_slope_deg must be < 90, got {cfg.tip_over_slope_deg!r}")
    if not cfg.dt * cfg.odometry_rate >= 1 - 1e-9:
        raise ValueError(
            f"odometry_rate must be at least 1/dt = {1 / cfg.dt:g} Hz, "
            f"got {cfg.odometry_rate!r}"
        )


def _check_team(cfg: ScenarioConfig) -> None:
    check_estimator("estimator", cfg.estimator)
    if not cfg.team:
        raise ValueError("team must hold at least one RobotSpec, got ()")
    for spec in cfg.team:
        if not isinstance(spec, RobotSpec):
            raise ValueError(f"team entries must be RobotSpec or dict, got {spec!r}")
        spec.validate()


def _check_world(cfg: ScenarioConfig) -> None:
    if len(cfg.world_size) != 2 or not all(
        isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in cfg.world_size
    ):
        raise ValueError(f"world_size must be two positive numbers, got {cfg.world_size!r}")
    for obstacle in cfg.obstacles:
        if not isinstance(obstacle, Obstacle):
            raise ValueError(f"obstacles entries must be Obstacle, got {obstacle!r}")
        obstacle.validate()
    for key in ("gps_open_sky_satellites", "gps_canopy_satellites"):
        lo, hi = getattr(cfg, key)
        if not (0 <= lo <= hi):
            raise ValueError(f"{key} must be (low, high) with 0 <= low <= high, got {(lo, hi)}")


def _check_start(cfg: ScenarioConfig) -> None:
    if cfg.start_region is not None:
        x0, y0, x1, y1 = cfg.start_region
        w, h = cfg.world_size
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise ValueError(
                f"start_region must be (x0, y0, x1, y1) inside the world, "
                f"got {cfg.start_region!r}"
            )
    cfg.check_team_size()
    if cfg.start_poses is not None:
        if len(cfg.start_poses) < cfg.n_robots:
            raise ValueError(
                f"start_poses lists {len(cfg.start_poses)} poses for n_robots={cfg.n_robots}"
            )
        for pose in cfg.start_poses:
            if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
                raise ValueError(f"start_poses entries must be finite (x, y, heading): {pose}")


def _check_extensions(cfg: ScenarioConfig) -> None:
    """The registered parts a config names: ``extras`` keys, observation blocks, reward
    terms."""
    validate_extras(cfg)
    check_obs_blocks(cfg.extra_obs_blocks)
    check_reward_config(cfg.extra_reward_terms, cfg.reward_weights)


#: What :meth:`ScenarioConfig.validate` runs, in order.
_CHECKS = (_check_counts, _check_choices, _check_flags, _check_info_keys, _check_numbers,
           _check_team, _check_world, _check_start, _check_extensions)


def _int_at_least(cfg: ScenarioConfig, key: str, low: int) -> None:
    value = getattr(cfg, key)
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{key} must be an integer >= {low}, got {value!r}")


def _number(
    cfg: ScenarioConfig, key: str, lower: float, strict: bool, upper: float | None = None
) -> None:
    value = getattr(cfg, key)
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = value > lower if strict else value >= lower
    if ok and upper is not None:
        ok = value <= upper
    if not ok:
        bound = f"> {lower}" if strict else f">= {lower}"
        if upper is not None:
            bound += f" and <= {upper}"
        raise ValueError(f"{key} must be a finite number {bound}, got {value!r}")


def _team_specs(team: Any) -> Any:
    """``team=`` as a tuple of :class:`RobotSpec`: dict entries (YAML, ``--set``) become specs.

    A mapping's keys must be :class:`RobotSpec` fields (else ``ValueError`` naming the
    key); entries of any other type are left for :meth:`ScenarioConfig.validate` to refuse.
    """
    if isinstance(team, (RobotSpec, Mapping)):
        team = (team,)
    if not isinstance(team, (tuple, list)):
        return team
    fields = {f.name for f in dataclasses.fields(RobotSpec)}
    specs = []
    for entry in team:
        if isinstance(entry, Mapping):
            unknown = [k for k in entry if k not in fields]
            if unknown:
                raise ValueError(
                    f"unknown RobotSpec key(s) {unknown} in team entry {dict(entry)!r}; "
                    f"known keys: {', '.join(sorted(fields))}"
                )
            entry = RobotSpec(**entry)
        specs.append(entry)
    return tuple(specs)
