"""Monte Carlo localization backend (Fox, Burgard, Kruppa, Thrun): ``estimator="mcl"``.

One class in one file on purpose (about 1,000 lines): every pass of a step (resampling,
motion, weighting, detections and their conflicts, symmetric copies) reads the same
per-robot filters, evidence ring and conflict records of :class:`MCLBackend`.

Each MCL robot keeps its own particle set (:class:`estimators.mcl.filter.ParticleFilter`)
in a known map built from the scenario's layout. Per env step and robot:

1. resample when the effective sample size falls below half the count
   (low-variance, with random particles injected and KLD-sampling of the count
   between ``n_min`` and ``n_particles``, the maximum); with
   ``extras["mcl_random_every_step"]`` at every step, as the paper's sampling
   importance resampling does, so its few uniform random particles enter after
   every estimation step;
2. predict with the step's odometry sub-steps (one composed motion);
3. weight by the range scan: the likelihood-field model for a laser (or the
   beam model without cones, ``extras["mcl_laser_model"] = "beam"``), the beam
   model with wide cones for a sonar (``cone_half_width = 0.5 * sonar_fov / sonar_beams``);
   beam models look expected ranges and likelihoods up in tables built once per
   map (:mod:`estimators.mcl.beam_table`), all robots of a sensor type in one call
   (:func:`estimators.mcl.batch.update_beam_batch`);
4. weight by DGPS fixes and compass readings when the robot has them
   (Gaussian likelihoods with the variances the receivers report);
5. detections between two MCL robots (``cooperative_updates``): the observed
   robot's belief is multiplied by the density of where the observer's particles
   say it is (:class:`estimators.mcl.detection_transfer.DetectionTransfer`, density
   trees, the paper's 2.5 m lockout, negative sightings ignored; the factor may
   be tempered, ``extras["mcl_detection_exponent"]``). Without
   ``cfg.detection_orientation`` the transfer samples (x, y) only. Every
   detection is first checked against both robots' beliefs
   (:mod:`estimators.mcl.detection_consistency`, ``extras["mcl_detection_check"]``,
   on by default): one that contradicts a confident detected robot is not
   transferred but counted as a conflict for both robots (info
   ``detection_conflicts``), and once a second conflict confirms it, each
   robot's own recent scans decide whom to trust, or both keep a minority
   hypothesis where the other claims they are (:meth:`MCLBackend._widen`).
6. symmetric copies (``extras["mcl_symmetry_check"]``, on by default; beam models
   only): the turns under which a map looks the same are found once per grid
   (:mod:`estimators.mcl.map_symmetry`); a robot whose main mode holds most of its
   weight keeps ``KEEP_MASS`` on every turned copy of it that its remembered scans,
   weighed along its odometry, and the detections it received from teammates that
   know which copy they are on, do not reject (:meth:`MCLBackend.keep_copies`, its
   per-step passes compiled in :mod:`estimators.mcl.copy_keeper`). With
   ``extras["mcl_calibrated_copies"]`` (off by default: the hallway step costs about
   three times as much) the top mode and those copies share the weight as that
   evidence weighs them instead, so the top mode's weight is the chance that it is the
   right copy (:mod:`estimators.mcl.copy_weights`). A
   filter with a bounded particle budget otherwise keeps whichever copies happened
   to hold particles when the scans stopped being ambiguous along whole corridors,
   and reports one of them sharply before the robot has seen what breaks the
   symmetry. A detection by such a teammate that puts the robot on one of its kept
   copies is applied without the consistency check (:meth:`MCLBackend._picks_kept_copy`).

Maps: one :class:`~estimators.mcl.occupancy.OccupancyGrid` per range-sensor type,
rasterized from ``world.layout.obstacles`` honouring each obstacle's
``visible_to`` (a laser robot's map lacks the sonar-only features) plus the
world's border. Grids and their derived tables are cached per process, so
many envs of one scenario share them. The resolution is
``max(0.1, max(world_size) / 160)`` m unless the scenario sets
``extras["mcl_resolution"]``; other :class:`MCLConfig` fields can be set
through ``extras["mcl"]`` (a dict), per sensor type through
``extras["mcl_laser"]`` / ``extras["mcl_sonar"]`` (applied on top).

Initial belief: uniform over the free space when ``cfg.global_localization``
(the paper's global localization; ``extras["mcl_global_init_factor"]`` times
``n_particles`` at first, 4 by default, cut by KLD-sampling), otherwise Gaussian around a noisy draw
around the true start (``init_pos_std``, ``init_heading_std``), as the EKF.

Not handled: detections between an MCL robot and a robot running another
estimator (EKF/MLE) are ignored by this backend (and by the EKF's); the
relative measurement would need a Gaussian <-> particle conversion.

Steps 1-4 run for the whole team at once, as compiled passes over one flat
array of all robots' particles (:mod:`estimators.mcl.batch`; each filter keeps
its own random generator, so the result equals stepping the robots one by
one), and the means, covariances, features and particle spreads of all
filters are computed together once per step.

Observation features: :meth:`ParticleFilter.belief_features` (48 values, layout
in :func:`estimators.mcl.filter.belief_feature_names`): weighted mean and
covariance (as the EKF's first ten entries), heading resultant, normalized
effective sample size, histogram entropy, particle-count fraction, a 5 x 5
egocentric histogram of particle mass (``HIST_CELL`` m cells) plus the mass
outside it, and an 8-bin heading histogram.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from coop_loc_env.backends.base import EstimatorBackend, noisy_start
from coop_loc_env.backends.mcl_options import check_extra
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.records import Beliefs, ParticleSet
from coop_loc_env.sensors import Readings, beam_angles
from coop_loc_env.world import World
from estimators.mcl.batch import (
    belief_summaries,
    compose_odometry_batch,
    particle_spreads,
    predict_batch,
    update_beam_batch,
    weigh_batch,
)
from estimators.mcl.beam_table import BeamLUT, RangeTable
from estimators.mcl.copy_keeper import filter_mode, mode_weight_below, top_up_copies
from estimators.mcl.copy_keeper import load_kernels as load_keeper_kernels
from estimators.mcl.copy_weights import (
    TOP_MODE_HEADING_TOL,
    hypothesis_shares,
    near_pose,
    set_group_masses,
    top_mode,
)
from estimators.mcl.copy_weights import load_kernels as load_top_mode_kernels
from estimators.mcl.density_tree import load_kernels
from estimators.mcl.detection_consistency import (
    ConsistencyConfig,
    backtrack,
    main_mode,
    move_rigidly,
    pose_estimate,
    scan_loglik_along,
    widen,
)
from estimators.mcl.detection_transfer import (
    DetectionTransfer,
    RobotDetection,
    TransferConfig,
    detection_from_measurement,
    sample_detected_poses,
    sample_observer_poses,
)
from estimators.mcl.filter import (
    MCLConfig,
    ParticleFilter,
    ParticleMotionNoise,
    belief_feature_names,
    low_variance_indices,
)
from estimators.mcl.map_symmetry import map_symmetries, symmetric_copies
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.sampling import resample_team
from estimators.mcl.team import ParticleTeam

__all__ = ["MCLBackend", "beam_angles", "known_map", "map_resolution"]

HIST_CELLS = 5
HIST_CELL = 1.0  # m, edge of one egocentric histogram cell
HEADING_BINS = 8
RANGE_LOOKUP_BINS = 256
LOCKOUT_DISTANCE = 2.5  # m (Fox et al.)
RESET_STD = 1.0  # m: confident observers (position std below) seed uncertain targets (above)
GLOBAL_INIT_FACTOR = 4  # global localization starts with this many times n_particles
CONFLICT_M = 1.0  # m: detection vs confident target disagreement / agreement tolerance
CONFLICT_MIN_S = 2.0  # s: two conflicts this far apart at least ...
CONFLICT_WINDOW_S = 60.0  # s: ... and at most confirm each other
EVIDENCE_WINDOW_S = 60.0  # s of each robot's own odometry and scans weighed in a conflict
EVIDENCE_NATS = 10.0  # tempered log-likelihood by which a robot's own scans reject a claim
WEAK_NATS = 3.0  # ... and below which they cannot tell it from their own mode
EVIDENCE_TURNS = np.linspace(-0.18, 0.18, 7)  # rad: headings searched around a hypothesis
EVIDENCE_SHIFTS = (-0.3, 0.0, 0.3)  # m: and positions along x and y
_EVIDENCE_GRID = np.array([(dx, dy, dth) for dth in EVIDENCE_TURNS for dx in EVIDENCE_SHIFTS
                           for dy in EVIDENCE_SHIFTS])
_EVIDENCE_HEADINGS = np.column_stack([np.zeros((len(EVIDENCE_TURNS), 2)), EVIDENCE_TURNS])
ADOPT_MASS = 0.9  # weight a robot whose scans cannot tell gives a claim its teammate's back
SYMMETRY_OVERLAP = 0.75  # share of a map's walls a turn must map onto walls to be a symmetry
KEEP_MASS = 0.005  # weight each symmetric copy of a robot's pose its scans cannot reject keeps
KEEP_CHECK_MASS = 0.8  # a robot whose main mode holds this much weight is checked ...
KEEP_CHECK_EVERY = 4  # ... every this many steps, once it has this much history:
KEEP_MIN_HISTORY_S = 1.0
KEEP_WINDOW_S = 30.0  # s of history the check weighs (a longer backtrack drifts into walls)
_GRID_CACHE: OrderedDict[tuple, OccupancyGrid] = OrderedDict()
_GRID_CACHE_SIZE = 16


def map_resolution(cfg: ScenarioConfig) -> float:
    """Cell size (m) of the MCL maps: ``extras["mcl_resolution"]`` or from the world size."""
    res = cfg.extras.get("mcl_resolution")
    check_extra("mcl_resolution", res)
    if res is None:
        return max(0.1, max(cfg.world_size) / 160.0)
    return float(res)


def mcl_overrides(cfg: ScenarioConfig, sensor: str | None = None) -> dict:
    """:class:`MCLConfig` fields a scenario sets through ``extras["mcl"]`` (validated), updated
    by ``extras["mcl_laser"]`` / ``extras["mcl_sonar"]`` for a ``sensor`` robot's filter."""
    out: dict = {}
    for key in ("mcl", "mcl_laser", "mcl_sonar"):  # all validated, whichever robots exist
        tuned = cfg.extras.get(key, {})
        check_extra(key, tuned)
        if key in ("mcl", f"mcl_{sensor}"):
            out.update(tuned)
    return out


def laser_model(cfg: ScenarioConfig) -> str:
    """``extras["mcl_laser_model"]``: ``"likelihood_field"`` (default) or ``"beam"``.

    The likelihood field scores each beam endpoint by its distance to the nearest
    occupied cell, so an endpoint deep inside a thick wall or the solid outside
    of a room scores as well as one on its surface (a pose whose beams "see
    through" a wall is not penalized). The beam model (Fox et al.'s Fig. 1:
    Gaussian around the ray-cast range, short readings, max-range readings)
    compares ranges and has no such blind spot; laser robots then use the same
    model as sonars, with ray casts from the grid's range table and no cone.
    """
    m = cfg.extras.get("mcl_laser_model", "likelihood_field")
    check_extra("mcl_laser_model", m)
    return m


def detection_reset_fraction(cfg: ScenarioConfig) -> float:
    """``extras["mcl_detection_reset"]``: fraction of a detected robot's particles re-seeded
    from a confident observer's detection (0, the default, is the paper's pure transfer)."""
    f = cfg.extras.get("mcl_detection_reset", 0.0)
    check_extra("mcl_detection_reset", f)
    return float(f)


def detection_check(cfg: ScenarioConfig) -> bool:
    """``extras["mcl_detection_check"]``: check every detection against both beliefs
    before transferring it (True, the default; False is Fox et al.'s transfer alone, as
    the ``paper`` profile runs it)."""
    f = cfg.extras.get("mcl_detection_check", True)
    check_extra("mcl_detection_check", f)
    return f


def symmetry_check(cfg: ScenarioConfig) -> bool:
    """``extras["mcl_symmetry_check"]``: keep the map's symmetric copies of a robot's main
    mode alive while its own scans cannot reject them (True, the default; False is Fox et
    al.'s filter alone, as the ``paper`` profile runs it; see :meth:`MCLBackend.keep_copies`)."""
    f = cfg.extras.get("mcl_symmetry_check", True)
    check_extra("mcl_symmetry_check", f)
    return f


def calibrated_copies(cfg: ScenarioConfig) -> bool:
    """``extras["mcl_calibrated_copies"]``: the kept symmetric copies share the top mode's
    weight as the evidence weighs them, so its weight is the chance that it is the right
    copy (True; :meth:`MCLBackend._keep_shared_copies`: the hallway step costs about
    three times as much), or each keeps a token ``KEEP_MASS`` and the top mode reports
    0.9-0.99 whichever copy it is on (False, the default;
    :meth:`MCLBackend._keep_token_copies`)."""
    f = cfg.extras.get("mcl_calibrated_copies", False)
    check_extra("mcl_calibrated_copies", f)
    return f


def global_init_factor(cfg: ScenarioConfig) -> int:
    """``extras["mcl_global_init_factor"]``: how many times ``n_particles`` the first,
    uniform particle set of global localization holds (``GLOBAL_INIT_FACTOR`` by default;
    KLD-sampling cuts it at the first resampling, so only adaptive filters use it)."""
    f = cfg.extras.get("mcl_global_init_factor", GLOBAL_INIT_FACTOR)
    check_extra("mcl_global_init_factor", f)
    return f


def detection_exponent(cfg: ScenarioConfig) -> float:
    """``extras["mcl_detection_exponent"]``: tempering of each belief transfer's factor
    (:attr:`TransferConfig.exponent`; 1, the default, is the paper's untempered Eq. 14)."""
    f = cfg.extras.get("mcl_detection_exponent", 1.0)
    check_extra("mcl_detection_exponent", f)
    return float(f)


def known_map(world: World, sensor: str, resolution: float) -> OccupancyGrid:
    """The occupancy grid a ``sensor`` (``"laser"``/``"sonar"``) robot localizes in (cached).

    Obstacles invisible to ``sensor`` are left out; the world's border is a wall.
    """
    if sensor not in ("laser", "sonar"):
        raise ValueError(f"sensor must be 'laser' or 'sonar', got {sensor!r}")
    obstacles = tuple(o for o in world.layout.obstacles if sensor in o.visible_to)
    size = tuple(float(v) for v in world.cfg.world_size)
    key = (size, float(resolution), obstacles)
    grid = _GRID_CACHE.get(key)
    if grid is not None:
        _GRID_CACHE.move_to_end(key)
        return grid
    circles = [(o.center, o.radius) for o in obstacles if o.shape == "circle"]
    segments = [(o.a, o.b, o.radius) for o in obstacles if o.shape == "segment"]
    polygons = [np.asarray(o.vertices, dtype=float) for o in obstacles if o.shape == "polygon"]
    # One ring of border cells just outside the world, so the walls sit at 0 and W, H.
    grid = OccupancyGrid.from_shapes(
        (size[0] + 2 * resolution, size[1] + 2 * resolution), resolution,
        origin=(-resolution, -resolution), circles=circles, segments=segments,
        polygons=polygons, border=True,
    )
    # Cells whose centre lies outside the world (where the size is not a multiple
    # of the resolution) are walls too.
    ny, nx = grid.shape
    centres = grid.cell_to_world(np.stack(np.meshgrid(np.arange(nx), np.arange(ny)), axis=-1))
    outside = (
        (centres[..., 0] < 0) | (centres[..., 0] > size[0])
        | (centres[..., 1] < 0) | (centres[..., 1] > size[1])
    )
    grid = OccupancyGrid(grid.occupied | outside, resolution, grid.origin)
    _GRID_CACHE[key] = grid
    while len(_GRID_CACHE) > _GRID_CACHE_SIZE:
        _GRID_CACHE.popitem(last=False)
    return grid


class MCLBackend(EstimatorBackend):
    """Per-robot particle filters with detection-based belief transfer for ``robots``.

    Args:
        cfg: the scenario (``n_particles`` is each filter's maximum count).
        robots: global indices of the robots that run MCL.
        world: the world, for its known static layout (never its robot poses).
    """

    feature_names = tuple(belief_feature_names(HIST_CELLS, HEADING_BINS))
    feature_size = len(feature_names)

    def __init__(self, cfg: ScenarioConfig, robots: np.ndarray, world: World | None = None) -> None:
        if world is None:
            raise ValueError("the MCL backend needs the world (its known map), got world=None")
        self.cfg = cfg
        self.robots = np.asarray(robots, dtype=int)
        self._local = {int(g): i for i, g in enumerate(self.robots)}
        specs = [cfg.robot_spec(int(g)) for g in self.robots]
        self._has_range = np.array([s.has_range_sensor for s in specs])
        self._sonar = np.array([s.range_sensor == "sonar" for s in specs])
        self._has_gps = np.array([s.has_gps for s in specs])
        self._has_compass = np.array([s.has_compass for s in specs])
        # the same as Python lists, read robot by robot at every step
        self._robot_ids = self.robots.tolist()
        self._has_range_l = self._has_range.tolist()
        self._has_gps_l = self._has_gps.tolist()
        self._has_compass_l = self._has_compass.tolist()
        self._kinds = ["sonar" if s else "laser" for s in self._sonar.tolist()]
        res = map_resolution(cfg)
        self._grids = {
            t: known_map(world, t, res)
            for t in {("sonar" if s else "laser") for s in self._sonar}
        }
        self._angles = {t: beam_angles(cfg, t == "sonar") for t in self._grids}
        self._cone = 0.5 * np.deg2rad(cfg.sonar_fov_deg) / cfg.sonar_beams
        # plain floats read at every step (config attribute lookups add up per robot)
        self.config_fields = {k: float(getattr(cfg, k)) for k in (
            "sonar_max_range", "laser_max_range", "compass_std")}
        n = cfg.n_particles
        # Motion-noise floors are per prediction (one per env step): scale them with dt.
        motion = ParticleMotionNoise(min_xy=0.02 * cfg.dt / 0.1, min_heading=0.01 * cfg.dt / 0.1)
        self._laser_beam = laser_model(cfg) == "beam"
        self.mcl_config = {}
        for t in self._grids:
            fields = {
                "n_particles": n,
                "motion": motion,
                "adaptive": True,
                "n_max": n,
                "n_min": 100,
                "beam_sigma": max(0.3, 2 * cfg.sonar_range_std),
                "lf_sigma": max(0.2, 2 * cfg.laser_range_std),
                "beam_lookup_bins": RANGE_LOOKUP_BINS if t == "sonar" or self._laser_beam else 0,
                **mcl_overrides(cfg, t),
            }
            fields["n_min"] = min(n, fields["n_min"])  # a smaller n_particles caps it
            self.mcl_config[t] = MCLConfig(**fields)
        self.transfer = DetectionTransfer(
            TransferConfig(
                lockout_distance=LOCKOUT_DISTANCE,
                false_positive_prob=max(cfg.false_positive_prob, 1e-3),
                n_samples=min(n, 1000),
                exponent=detection_exponent(cfg),
                consistency=ConsistencyConfig() if detection_check(cfg) else None,
            )
        )
        self.check = self.transfer.config.consistency
        # the turns under which each sensor type's map looks the same (beam models only:
        # the scans are weighed again along the odometry with the beam tables)
        self.symmetries = {t: map_symmetries(g, SYMMETRY_OVERLAP) for t, g in self._grids.items()
                           if symmetry_check(cfg) and (t == "sonar" or self._laser_beam)}
        self._keeps_history = self.check is not None or any(self.symmetries.values())
        self.calibrated = calibrated_copies(cfg)
        self._keep = self._keep_shared_copies if self.calibrated else self._keep_token_copies
        self.reset_fraction = detection_reset_fraction(cfg)
        self.resample_every_step = cfg.extras.get("mcl_random_every_step", False)
        check_extra("mcl_random_every_step", self.resample_every_step)
        self.init_factor = global_init_factor(cfg)
        self.filters: list[ParticleFilter] = []
        self._origins = np.zeros((0, 2))  # each filter's state origin (world x, y)
        self._origins_l: list[list[float]] = []
        self.rng = np.random.default_rng(0)
        self.transfers_applied = np.zeros(len(self.robots), dtype=int)
        self.detection_conflicts = np.zeros(len(self.robots), dtype=int)
        self._certified = np.zeros(len(self.robots), dtype=bool)
        self._t = 0
        self._conflicts: dict[int, list] = {}
        self._summary: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._modes: dict[int, tuple] = {}  # filter -> its state's main mode (:meth:`_mode`)

    # ------------------------------------------------------------------ reset
    def _sensor(self, i: int) -> str:
        return "sonar" if self._sonar[i] else "laser"

    def reset(self, true_poses: np.ndarray, rng: np.random.Generator) -> None:
        """New filters: uniform (global localization) or Gaussian around a noisy start."""
        cfg = self.cfg
        k = len(self.robots)
        start, std = noisy_start(cfg, true_poses, self.robots, rng)
        cov = np.diag(std**2)
        seeds = rng.integers(2**63, size=k + 1)
        self.rng = np.random.default_rng(int(seeds[-1]))
        self.filters = []
        for i in range(k):
            t = self._sensor(i)
            pf = ParticleFilter(
                self._grids[t], np.random.default_rng(int(seeds[i])), self.mcl_config[t]
            )
            if cfg.global_localization:
                # Dense first set: every symmetric copy of the true pose gets
                # particles near it; KLD-sampling cuts it to n_particles at the
                # first resampling (a fixed-size filter keeps n_particles).
                factor = self.init_factor if pf.config.adaptive else 1
                pf.init_uniform(factor * pf.config.n_particles)
            else:
                pf.init_gaussian(start[i], cov)
            self.filters.append(pf)
        self._origins = np.array([pf.state_origin for pf in self.filters]).reshape(-1, 2)
        self._origins_l = self._origins.tolist()
        self.transfer.reset()
        self.transfers_applied[:] = 0
        self.detection_conflicts[:] = 0
        self._certified[:] = False
        self._plausible: list[list | None] = [None] * k
        self._shares: list[np.ndarray | None] = [None] * k  # of the mode and kept copies
        self._kept_top: list[np.ndarray | None] = [None] * k  # top mode at the last check
        # nats by which evidence older than the window favours the top mode over its copies:
        # a start known up to noise is such evidence
        self._prior = np.full(k, EVIDENCE_NATS if self.calibrated and not
                              cfg.global_localization else 0.0)
        self._transfers_in: list[list[tuple]] = [[] for _ in range(k)]
        self._t = 0
        self._conflicts = {}
        self._summary = None
        self._modes = {}
        if self._keeps_history:
            h = max(1, int(round(EVIDENCE_WINDOW_S / cfg.dt)))
            width = max((len(a) for a in self._angles.values()), default=0)
            self._hist_delta = np.zeros((h, k, 3))
            self._hist_scan = np.full((h, k, width), np.nan)
            self._hist_n = self._hist_next = 0
        if cfg.cooperative_updates:  # the first detection would load them inside a step
            load_kernels()
        for t, syms in self.symmetries.items():  # and the first step that keeps a copy
            if syms:
                load_keeper_kernels(self._grids[t])
                if self.calibrated:
                    load_top_mode_kernels()
        # build the shared range tables now, not inside the first step
        for i in range(k):
            if self._sonar[i]:
                self.filters[i].beam_tables(cfg.sonar_max_range, self._cone)
            elif self._laser_beam:
                self.filters[i].beam_tables(cfg.laser_max_range)

    # ------------------------------------------------------------------ step
    def step(self, readings: Readings, active: np.ndarray) -> dict[str, int]:
        """Predict, weight by range scans, DGPS, compass and detections; returns counts."""
        cfg = self.cfg
        dt_sub = cfg.dt / cfg.odometry_substeps
        stats = {"range_updates": 0, "detections_applied": 0, "detections_ignored": 0}
        self._t += 1
        self._summary = None
        active_l = active.tolist()
        live = [i for i, g in enumerate(self._robot_ids) if active_l[g]]
        team = [self.filters[i] for i in live]
        # Resample only when the weights degenerate (not on every step, as
        # ParticleFilter.resample_if_needed does while injection is on): every
        # resampling lets symmetric modes drift, so fewer keep them alive longer.
        # Random particles are injected at these resamplings.
        which = [self.resample_every_step
                 or pf.ess < pf.config.resample_ess_fraction * pf.n_particles for pf in team]
        if any(which):
            joined = ParticleTeam.gather(team)
            resample_team(joined, joined.weights(), which)
        if live:
            odo = readings.odometry[:, self.robots[live]]  # (substeps, robots, 2)
            deltas = compose_odometry_batch(odo[..., 0].T, odo[..., 1].T, dt_sub)
            predict_batch(team, deltas)
            if self._keeps_history:
                self._record(live, deltas, readings)
        stats["range_updates"] = self._measurement_updates(live, readings)
        det = readings.detections
        if cfg.cooperative_updates and len(det):
            for k in range(len(det)):
                a, b = int(det.observer[k]), int(det.target[k])
                if a not in self._local or b not in self._local:
                    continue  # cross-backend detections are ignored (see module docstring)
                ia, ib = self._local[a], self._local[b]
                if not (active[a] and active[b]):
                    continue
                observer, target = self.filters[ia], self.filters[ib]
                if self.transfer.lockout.is_locked(a, b, observer.odometer):
                    stats["detections_ignored"] += 1  # what transfer.apply would answer
                    continue
                rec = detection_from_measurement(a, b, det.z[k], det.cov[k])
                if not cfg.detection_orientation:
                    rec = replace(rec, orientation=None, orientation_std=None)
                if self.reset_fraction > 0:
                    self._detection_reset(ib, rec, observer, target)
                res = self.transfer.apply(rec, observer, target, self.rng,
                                          check=not self._picks_kept_copy(ia, ib, rec),
                                          hypotheses=self._hypotheses(ib))
                if res.applied:
                    stats["detections_applied"] += 1
                    self.transfers_applied[ib] += 1
                    if self.symmetries and (self._certified[ia] or (
                            self.calibrated and self._turns(ia) != self._turns(ib))):
                        # evidence on the target's copies: an observer that knows which copy
                        # it is on tells the target's; one whose map has other symmetries
                        # tells which of the target's copies fit with some copy of its own
                        # (the product of a two- and a three-copy belief has one common
                        # mode), while one that shares them cannot tell a team turned as a
                        # whole from the truth
                        self._transfers_in[ib].append((self._t, res.tree,
                                                       rec.orientation is not None))
                else:
                    stats["detections_ignored"] += 1
                    if res.reason == "conflict":
                        self.detection_conflicts[[ia, ib]] += 1
                        self._certified[[ia, ib]] = False
                        self._plausible[ia] = self._plausible[ib] = None
                        self._widen(ib, rec, observer, target)
        if self.symmetries:
            self.keep_copies(live)
        return stats

    def _turns(self, i: int) -> tuple:
        """The turns under which robot ``i``'s map looks the same (none without a beam
        model: its copies are not kept)."""
        return self.symmetries.get(self._kinds[i], ())

    def _hypotheses(self, i: int) -> np.ndarray | None:
        """Mask of robot ``i``'s particles near its top mode and the copies of it that it
        keeps (:meth:`keep_copies`), or None while it keeps none (always None with the token
        keeper, which sets no ``_kept_top``: the detection check then weighs the main mode)."""
        plausible, top = self._plausible[i], self._kept_top[i]
        if not plausible or top is None:
            return None
        radius = (self.check or ConsistencyConfig()).mode_radius
        centres = np.array([top[:2], *(symmetric_copies(top, s)[:2] for s in plausible)])
        xy = self.filters[i].particles[:, :2]
        d2 = ((xy[:, None] - centres[None]) ** 2).sum(axis=2)
        return d2.min(axis=1) <= radius * radius

    def _picks_kept_copy(self, ia: int, ib: int, rec: RobotDetection) -> bool:
        """Whether a certified observer ``ia`` puts an uncertified target ``ib`` on one of the
        symmetric copies of its main mode that it keeps (:meth:`keep_copies`), within
        ``CONFLICT_M``.

        The target's scans cannot reject that copy, and the observer's reject every copy of
        its own pose, so the detection tells the target which copy it is on: its weight
        moving from the main mode to the copy is the kept copy taking over, not a conflict
        (the consistency check would refuse it, the main mode looking confident).
        """
        plausible = self._plausible[ib]
        if not (plausible and self._certified[ia]) or self._certified[ib]:
            return False
        radius = (self.check or ConsistencyConfig()).mode_radius
        observer, target = self.filters[ia], self.filters[ib]
        o = pose_estimate(observer.particles, observer.weights, radius)
        implied = o[:2] + rec.range * np.array([math.cos(o[2] + rec.bearing),
                                                math.sin(o[2] + rec.bearing)])
        own = pose_estimate(target.particles, target.weights, radius)
        copies = np.array([symmetric_copies(own, s)[:2] for s in plausible])
        return bool((np.hypot(*(copies - implied).T) <= CONFLICT_M).any())

    def keep_copies(self, live: list[int]) -> None:
        """Keep the map's symmetric copies of each live robot's main mode alive while the
        robot's own scans cannot reject them (:mod:`estimators.mcl.map_symmetry`): each
        with a token weight (:meth:`_keep_token_copies`, the default) or sharing the top
        mode's weight as the evidence weighs them (:meth:`_keep_shared_copies`,
        ``extras["mcl_calibrated_copies"]``)."""
        self._keep(live)

    def _keep_token_copies(self, live: list[int]) -> None:
        """:meth:`keep_copies` with a token weight on each copy (the default).

        A robot whose main mode holds ``KEEP_CHECK_MASS`` of its weight is checked every
        ``KEEP_CHECK_EVERY`` steps (:meth:`_plausible_copies`); every copy the check found
        plausible keeps ``KEEP_MASS`` of the weight at every step until the next check (the
        main mode's cloud turned there, in place of the least likely particles:
        :func:`~estimators.mcl.detection_consistency.widen`), so the reported belief is not
        confident while the map cannot be told apart, and the copy takes over if the main
        mode was the wrong one when the robot reaches a feature that breaks the symmetry
        or a certified teammate detects it on the copy (:meth:`_picks_kept_copy`).
        A robot whose evidence rejects every copy by ``EVIDENCE_NATS`` is certified and not
        checked again until its main mode loses that weight or a detection conflicts with it.
        """
        if self._hist_n * self.cfg.dt < KEEP_MIN_HISTORY_S:
            return
        radius = (self.check or ConsistencyConfig()).mode_radius
        for i in live:
            syms = self.symmetries.get(self._kinds[i])
            if not syms:
                continue
            # a spread-out belief's mode cannot hold KEEP_CHECK_MASS: a bound settles it
            below = self._cached_mode(i, radius) is None and mode_weight_below(
                self.filters[i].particle_set, radius, KEEP_CHECK_MASS)
            if not below:
                mode, mass = self._mode(i, radius)
                below = mass < KEEP_CHECK_MASS
            if below:
                self._certified[i] = False
                self._plausible[i] = None
                continue
            if self._certified[i]:
                continue
            pf = self.filters[i]
            parts, w = pf.particles, pf.weights
            cloud = parts[mode]
            if self._plausible[i] is None or self._t % KEEP_CHECK_EVERY == 0:
                self._plausible[i], _ = self._plausible_copies(i, cloud, w[mode], syms, radius)
            if not self._plausible[i]:
                continue
            # each copy's particles turned from the main mode's and its weight topped up to
            # KEEP_MASS (compiled; most copies still hold it from an earlier step)
            parts, w, placed = top_up_copies(parts, w, cloud, self._plausible[i], KEEP_MASS,
                                             radius, self.rng, pf.grid)
            if placed:
                pf.set_particles(parts, w)

    def _keep_shared_copies(self, live: list[int]) -> None:
        """:meth:`keep_copies` with the copies sharing the top mode's weight
        (``extras["mcl_calibrated_copies"]``).

        A robot whose top mode (as ``belief_modes`` extracts it:
        :func:`~estimators.mcl.copy_weights.top_mode`) holds, with the particles near its
        turned copies, ``KEEP_CHECK_MASS`` of its weight is checked every
        ``KEEP_CHECK_EVERY`` steps, and whenever its top mode jumps
        (:meth:`_plausible_copies`); until the next check the mode and every copy the check
        found plausible share that mass as the evidence weighs them, at least ``KEEP_MASS``
        each (:func:`~estimators.mcl.copy_weights.set_group_masses`: the mode's cloud
        turned onto a copy that holds too few particles), so the top mode's weight is the
        chance that it is the right copy, and the copy takes over when the robot reaches a
        feature that breaks the symmetry or a certified teammate detects it on the copy.
        A robot whose evidence rejects every copy by ``EVIDENCE_NATS`` is certified and not
        checked again until its main mode loses that weight or a detection conflicts with it.
        """
        if self._hist_n * self.cfg.dt < KEEP_MIN_HISTORY_S:
            return
        radius = (self.check or ConsistencyConfig()).mode_radius
        bounds = (0.0, 0.0, *(float(v) for v in self.cfg.world_size))
        for i in live:
            syms = self.symmetries.get(self._kinds[i])
            if not syms:
                continue
            pf = self.filters[i]
            # a spread-out belief: no disc of the radius holds the share of KEEP_CHECK_MASS
            # that the mode and its copies would need each, a bound settles it (compiled)
            below = mode_weight_below(pf.particle_set, radius,
                                      KEEP_CHECK_MASS / (1 + len(syms)))
            if not below:
                parts, w = pf.particles, pf.weights
                top, _ = top_mode(parts, w, radius, TOP_MODE_HEADING_TOL, bounds)
                mode = near_pose(parts, top, radius, TOP_MODE_HEADING_TOL)
                group = float(w[mode].sum()) + sum(
                    float(w[near_pose(parts, symmetric_copies(top, s), radius,
                                      TOP_MODE_HEADING_TOL)].sum()) for s in syms)
                below = group < KEEP_CHECK_MASS or not mode.any()
            # a belief below the bound keeps no copies: its top mode is not needed (the
            # next check is forced by the cleared copies, not by a jump of the mode)
            last, self._kept_top[i] = self._kept_top[i], None if below else top
            if below:
                self._certified[i] = False
                self._plausible[i] = None
                self._prior[i] = 0.0
                continue
            if self._certified[i]:
                continue
            cloud = parts[mode]
            jumped = last is not None and math.hypot(*(top[:2] - last[:2])) > radius
            if jumped:
                self._prior[i] = 0.0  # what it knew was about another copy
            if self._plausible[i] is None or jumped or self._t % KEEP_CHECK_EVERY == 0:
                self._plausible[i], self._shares[i] = self._plausible_copies(
                    i, cloud, w[mode], syms, radius)
            if not self._plausible[i]:
                continue
            centres, clouds = [top[:2]], [cloud]
            for sym in self._plausible[i]:
                turned = symmetric_copies(cloud, sym)
                centres.append(symmetric_copies(top, sym)[:2])
                clouds.append(turned[pf.grid.is_free(turned[:, :2])])
            masses = np.maximum(self._shares[i] * group, KEEP_MASS)
            masses[0] = max(group - masses[1:].sum(), KEEP_MASS)
            parts, w, _ = set_group_masses(parts, w, np.array(centres), clouds, masses,
                                           radius, self.rng)
            pf.set_particles(parts, w)

    def _mode(self, i: int, radius: float) -> tuple[np.ndarray, float]:
        """Filter ``i``'s main mode (the mask of
        :func:`~estimators.mcl.detection_consistency.main_mode` over its particles) and the
        weight in it, computed once per state of the filter: cached until a step begins or
        the filter's particles, weights or motion count change."""
        hit = self._cached_mode(i, radius)
        if hit is not None:
            return hit
        ps = self.filters[i].particle_set
        mode, mass = filter_mode(ps, radius)
        mode.flags.writeable = False
        self._modes[i] = (self._t, ps.state, ps.weights, ps.unwrapped_steps, radius, mode, mass)
        return mode, mass

    def _cached_mode(self, i: int, radius: float) -> tuple[np.ndarray, float] | None:
        """:meth:`_mode`'s answer for filter ``i``'s current state, if it has one."""
        hit = self._modes.get(i)
        if hit is None:
            return None
        ps = self.filters[i].particle_set
        t, state, weights, steps, r, mode, mass = hit
        if (t == self._t and state is ps.state and weights is ps.weights
                and steps == ps.unwrapped_steps and r == radius):
            return mode, mass
        return None

    def _plausible_copies(self, i: int, cloud: np.ndarray, weights: np.ndarray,
                          syms: tuple, radius: float) -> tuple[list, np.ndarray]:
        """The symmetries whose copy of robot ``i``'s main mode (particles ``cloud``) its
        evidence does not reject by ``WEAK_NATS``, and the shares of the mode and those
        copies in the posterior the evidence gives them
        (:func:`~estimators.mcl.copy_weights.hypothesis_shares`); certifies the robot when
        it rejects every copy by ``EVIDENCE_NATS``.

        The evidence: the robot's scans of the last ``KEEP_WINDOW_S`` weighed along its
        odometry back from its main mode's pose (a few headings around it,
        ``EVIDENCE_TURNS``; with ``mcl_calibrated_copies`` also ``EVIDENCE_SHIFTS``) and
        from each copy of those poses (the same trajectories turned, so the two differ
        only where the map does), plus the detection transfers it received from certified
        observers (and, with ``mcl_calibrated_copies``, from observers whose maps have
        other symmetries; :meth:`_detection_loglik`: an observer that knows which copy it
        is on tells the target's too; one whose map has other turns rules out the target's
        copies that fit none of its own; one that shares them and does not know its copy
        is blind to the team's being turned as a whole). With ``mcl_calibrated_copies`` a
        robot once certified on its top mode keeps ``EVIDENCE_NATS`` in its favour
        (evidence older than the window, kept until the top mode jumps to another place or
        loses its weight): a detection that conflicts with it (most are false positives)
        has it checked again, not forget what it saw.
        """
        own = pose_estimate(cloud, weights, radius)
        cands = own + (_EVIDENCE_GRID if self.calibrated else _EVIDENCE_HEADINGS)
        copies = [symmetric_copies(cands, s) for s in syms]
        pf = self.filters[i]
        table, lut, angles, _ = self.beam_model(i)
        deltas, scans = self._history(i, len(angles))
        h = max(1, int(round(KEEP_WINDOW_S / self.cfg.dt)))
        paths = backtrack(np.concatenate([cands, *copies]), deltas[-h:])
        ll = scan_loglik_along(table, lut, pf.state_origin, angles, paths, scans[-h:],
                               pf.config.occupied_loglik)
        ll = (ll + self._detection_loglik(i, paths)).reshape(1 + len(syms), -1)
        best = ll.max(axis=1)
        best[0] += self._prior[i]
        gaps = best[0] - best[1:]
        self._certified[i] = bool((gaps >= EVIDENCE_NATS).all())
        if self._certified[i] and self.calibrated:
            self._prior[i] = EVIDENCE_NATS
        kept = [j for j, gap in enumerate(gaps.tolist()) if gap < WEAK_NATS]
        return [syms[j] for j in kept], hypothesis_shares(best[[0, *(1 + j for j in kept)]])

    def _record(self, live: list[int], deltas: np.ndarray, readings: Readings) -> None:
        """Remember each live robot's odometry motion and beam-model scan of this step (the
        evidence :meth:`_evidence` weighs; robots without a beam model keep no scans)."""
        hd, hs = self._hist_delta, self._hist_scan
        row = self._hist_next  # a ring: row ``_hist_next - 1`` is the newest
        hd[row] = 0.0
        hs[row] = np.nan
        hd[row, live] = deltas
        mask = readings.range_mask
        for i in live:
            g = self._robot_ids[i]
            if self._has_range_l[i] and mask[g] and (self._sonar[i] or self._laser_beam):
                b = len(self._angles[self._kinds[i]])
                hs[row, i, :b] = readings.ranges[g, :b]
        self._hist_next = (row + 1) % len(hd)
        self._hist_n = min(self._hist_n + 1, len(hd))

    def _history(self, i: int, beams: int) -> tuple[np.ndarray, np.ndarray]:
        """Robot ``i``'s remembered odometry motions and scans, oldest first."""
        order = (self._hist_next - self._hist_n + np.arange(self._hist_n)) % len(self._hist_delta)
        return self._hist_delta[order, i], self._hist_scan[order, i, :beams]

    def _evidence(self, i: int, claimed: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """How strongly robot ``i``'s own recent scans prefer its main mode to ``claimed``
        poses (tempered log-likelihood ratio), and the best pose of each hypothesis.

        Each hypothesis (the main mode's pose, and the claim's:
        :func:`~estimators.mcl.detection_consistency.pose_estimate`) is searched over a
        small grid of poses around it (``EVIDENCE_TURNS`` x ``EVIDENCE_SHIFTS``: a claim is
        blurred by the detection noise, and a heading off by a few hundredths of a radian
        takes a trajectory into the walls a few tens of metres back); every pose is taken
        back along the robot's odometry over the last ``EVIDENCE_WINDOW_S``, its scans
        weighed along each trajectory, and the best of each hypothesis compared. A robot
        without a beam model has no evidence (0).
        """
        pf = self.filters[i]
        radius = self.check.mode_radius
        own = pose_estimate(pf.particles, pf.weights, radius)
        alt = pose_estimate(claimed, np.full(len(claimed), 1.0 / len(claimed)), radius)
        if not (self._sonar[i] or self._laser_beam) or self._hist_n == 0:
            return 0.0, own, alt
        table, lut, angles, _ = self.beam_model(i)
        deltas, scans = self._history(i, len(angles))
        offsets = _EVIDENCE_GRID
        cands = np.concatenate([own + offsets, alt + offsets])
        ll = scan_loglik_along(table, lut, pf.state_origin, angles, backtrack(cands, deltas),
                               scans, pf.config.occupied_loglik)
        k = len(offsets)
        best_own, best_alt = int(np.argmax(ll[:k])), int(np.argmax(ll[k:]))
        return float(ll[best_own] - ll[k + best_alt]), cands[best_own], cands[k + best_alt]

    def _widen(self, ib: int, rec: RobotDetection, observer: ParticleFilter,
               target: ParticleFilter) -> None:
        """Resolve a confirmed conflict between the observer and the target.

        Each robot's own recent scans are weighed at its main mode and at the
        pose the other claims for it (:meth:`_evidence`); a claim needs a
        confident claimant (position std below ``RESET_STD``). When both are
        confident and one robot's scans reject the other's claim (by
        ``EVIDENCE_NATS``) while the other's scans cannot tell its claim from
        its own mode (below ``WEAK_NATS``), the first is trusted: the other gives
        ``ADOPT_MASS`` of its weight to the trusted robot's claim (its own mode
        carried there rigidly, keeping the rest where it was). When no robot's
        scans reject a claim, each claimed-about robot keeps ``widen_mass`` where
        the other says it is (:func:`estimators.mcl.detection_consistency.widen`).
        Otherwise nothing changes. A single conflict may be a
        false positive, so this waits for a second (:meth:`_confirmed_conflict`).
        """
        obs_ok = self.claim_std(self._local[rec.observer]) < RESET_STD
        tgt_ok = self.claim_std(ib) < RESET_STD
        if not (obs_ok or tgt_ok) or not self._confirmed_conflict(ib, rec, observer, target,
                                                                  True):
            return
        cfg = self.check
        ia = self._local[rec.observer]
        n = max(8, int(round(2 * cfg.widen_mass * max(observer.n_particles,
                                                       target.n_particles))))
        claims = {}
        if obs_ok:  # the observer says where the target is
            draw = observer.particles[low_variance_indices(observer.weights, n, self.rng)]
            claimed = sample_detected_poses(draw, rec, self.rng)
            if rec.orientation is None:
                claimed[:, 2] = self.rng.uniform(-np.pi, np.pi, len(claimed))
            claims[ib] = claimed[target.grid.is_free(claimed[:, :2])]
        if tgt_ok:  # and the target where the observer is
            draw = target.particles[low_variance_indices(target.weights, n, self.rng)]
            claimed = sample_observer_poses(draw, rec, self.rng)
            claims[ia] = claimed[observer.grid.is_free(claimed[:, :2])]
        evidence, clouds = {}, {}
        for i, claimed in claims.items():
            if len(claimed) == 0:
                continue
            evidence[i], own, alt = self._evidence(i, claimed)
            # the robot's own main mode carried to the claim's best-fitting pose: the shape
            # its scans gave it fits there as well in a symmetric map, and a noisy draw from
            # the claim would lose weight to the well-fitted own mode while it settles
            pf = self.filters[i]
            mode, _ = self._mode(i, cfg.mode_radius)
            moved = move_rigidly(pf.particles[mode] if mode.any() else pf.particles, own, alt)
            clouds[i] = moved[pf.grid.is_free(moved[:, :2])]
        claims = {i: c for i, c in clouds.items() if len(c)}
        if not claims:
            return
        e_t, e_o = evidence.get(ib), evidence.get(ia)
        both = e_t is not None and e_o is not None
        if both and e_t < WEAK_NATS and e_o >= EVIDENCE_NATS:
            masses = {ib: ADOPT_MASS}  # the target's scans cannot tell; the observer's can
        elif both and e_o < WEAK_NATS and e_t >= EVIDENCE_NATS:
            masses = {ia: ADOPT_MASS}
        elif all(e < EVIDENCE_NATS for e in evidence.values()):
            masses = dict.fromkeys(claims, cfg.widen_mass)
        else:
            return
        for i, mass in masses.items():
            pf = self.filters[i]
            parts, weights, placed = widen(pf.particles, pf.weights, claims[i], mass,
                                           cfg.mode_radius, self.rng)
            if placed:
                pf.set_particles(parts, weights)

    def claim_std(self, i: int) -> float:
        """Position spread (m) of robot ``i``'s belief as a claim about where it is: its
        main mode's while it keeps symmetric copies of it (:meth:`keep_copies`; the copies
        say the map cannot tell, not that the robot is lost), else the whole set's
        (:meth:`ParticleFilter.position_std`)."""
        pf = self.filters[i]
        if not self._plausible[i]:
            return pf.position_std()
        radius = (self.check or ConsistencyConfig()).mode_radius
        parts, w = pf.particles, pf.weights
        mode, _ = self._mode(i, radius)
        wm = w[mode] / w[mode].sum()
        d = parts[mode, :2] - wm @ parts[mode, :2]
        return math.sqrt(0.5 * float(wm @ (d * d).sum(axis=1)))

    def _detection_loglik(self, i: int, paths: np.ndarray) -> np.ndarray:
        """Log of the factors the detection transfers robot ``i`` received within its
        remembered history would have given poses along ``paths`` ``(P, K, 3)`` (each
        transfer read at the step it came; older transfers are forgotten)."""
        out = np.zeros(len(paths))
        k = paths.shape[1]
        kept = []
        for t, tree, heading in self._transfers_in[i]:
            row = k - 1 - (self._t - t)
            if row < 0:
                continue
            kept.append((t, tree, heading))
            poses = paths[:, row] if heading else paths[:, row, :2]
            out += np.log(np.maximum(self.transfer.mixture_factors(tree, poses), 1e-300))
        self._transfers_in[i] = kept
        return out

    def _detection_reset(
        self, ib: int, rec: RobotDetection, observer: ParticleFilter, target: ParticleFilter
    ) -> None:
        """Seed the target with poses the detection implies, when the observer is confident.

        Replaces ``reset_fraction`` of the target's particles (chosen at random)
        by draws of the observer's particles pushed through the detection model,
        each with the target's mean weight; the density-tree reweighting that
        follows then decides between them and the target's own hypotheses. Only
        done when the observer's position std is below ``RESET_STD`` (a lost
        observer's detection implies no compact region worth seeding) and the
        target's is above it (a confident target keeps the paper's protection
        against false positives: a detection far from all its particles leaves
        its belief unchanged, whereas seeded particles would win any such
        comparison) -- unless the target is confidently wrong, which shows as
        a confirmed conflict (:meth:`_confirmed_conflict`).
        Without it the transfer can only reweight particles the target already
        has, and a target whose set collapsed onto a wrong mode of a symmetric
        map has none near the truth (sensor resetting, Lenser and Veloso 2000).
        With the consistency check on (:attr:`check`) an observer seeds only a target
        whose spread is larger than its own and that has no main mode (or, while it keeps
        symmetric copies, no mode and copies together: :meth:`_hypotheses`) holding
        ``confident_mass`` of its weight (a confident target that disagrees is a
        conflict, handled by :meth:`_widen`, never re-seeded).
        """
        obs_std = self.claim_std(self._local[rec.observer])
        if obs_std > RESET_STD:
            return
        if self.check is not None:
            if self.claim_std(ib) <= obs_std:
                return
            mode = self._hypotheses(ib)
            mass = (float(target.weights[mode].sum()) if mode is not None
                    else self._mode(ib, self.check.mode_radius)[1])
            if mass >= self.check.confident_mass:
                return
        elif target.position_std() <= RESET_STD and not self._confirmed_conflict(
            ib, rec, observer, target
        ):
            return
        n = target.n_particles
        m = int(round(self.reset_fraction * n))
        if m < 1:
            return
        idx = low_variance_indices(observer.weights, m, self.rng)
        seeds = sample_detected_poses(observer.particles[idx], rec, self.rng)
        grid = target.grid
        seeds = seeds[grid.is_free(seeds[:, :2])]
        if len(seeds) == 0:
            return
        parts = target.particles.copy()
        weights = target.weights.copy()
        slots = self.rng.choice(n, size=len(seeds), replace=False)
        parts[slots] = seeds
        weights[slots] = 1.0 / n
        target.set_particles(parts, weights)

    def _confirmed_conflict(
        self, ib: int, rec: RobotDetection, observer: ParticleFilter, target: ParticleFilter,
        conflict: bool = False,
    ) -> bool:
        """Whether a confident target's disagreement with detections is confirmed.

        A detection from a confident observer conflicts with a confident target
        when the position it implies is more than ``CONFLICT_M`` from the
        target's mean. A single conflict may be a false positive; it is
        confirmed when an earlier conflict (from ``CONFLICT_MIN_S`` to
        ``CONFLICT_WINDOW_S`` ago) implied a position whose distance from this
        one matches, within ``CONFLICT_M``, the distance the target's own belief
        moved meanwhile (false positives imply unrelated positions; a target
        locked onto a rotated copy of the map moves the same distances).
        With ``conflict`` (the consistency check already found one) the target's
        position is the centre of its main mode, and no distance test is made.
        """
        mean_o = observer.mean_pose()
        implied = mean_o[:2] + rec.range * np.array(
            [np.cos(mean_o[2] + rec.bearing), np.sin(mean_o[2] + rec.bearing)]
        )
        if conflict:
            mean_t, _ = main_mode(target.particles[:, :2], target.weights,
                                  self.check.mode_radius)
        else:
            mean_t = target.mean_pose()[:2]
            if np.hypot(*(implied - mean_t)) <= CONFLICT_M:
                return False
        now = self._t * self.cfg.dt
        history = [c for c in self._conflicts.get(ib, []) if now - c[2] <= CONFLICT_WINDOW_S]
        confirmed = any(
            now - t0 >= CONFLICT_MIN_S
            and abs(np.hypot(*(implied - p0)) - np.hypot(*(mean_t - m0))) <= CONFLICT_M
            for p0, m0, t0 in history
        )
        self._conflicts[ib] = [*history, (implied, mean_t, now)]
        if confirmed:
            self._conflicts[ib] = []
        return confirmed

    def _measurement_updates(self, live: list[int], readings: Readings) -> int:
        """Weight the live robots' particles by their range scans, DGPS fixes and compass
        readings; returns how many scans.

        Robots sharing a beam model (sonars; lasers with ``mcl_laser_model="beam"``)
        are weighted by their scans together (:func:`estimators.mcl.batch.update_beam_batch`);
        then the likelihood-field laser scans and all fixes in one pass
        (:func:`estimators.mcl.batch.weigh_batch`).
        """
        if not live:
            return 0
        cfg = self.config_fields
        robots = self._robot_ids
        team = [self.filters[i] for i in live]
        range_mask = readings.range_mask.tolist()
        scans: dict[str, list[int]] = {}  # positions in ``live`` of the robots with scans
        for k, i in enumerate(live):
            if self._has_range_l[i] and range_mask[robots[i]]:
                scans.setdefault(self._kinds[i], []).append(k)
        n_scans = sum(len(v) for v in scans.values())
        lf_ranges = None  # likelihood-field laser scans (rows of NaN: no scan)
        for t, sel in scans.items():
            angles = self._angles[t]
            rows = readings.ranges[[robots[live[k]] for k in sel], : len(angles)]
            finite = np.isfinite(rows)
            carry = finite.any(axis=1).tolist()  # a scan without a reading carries nothing
            if not all(carry):
                sel = [k for k, c in zip(sel, carry, strict=True) if c]
                if not sel:
                    continue
                rows, finite = rows[carry], finite[carry]
            if t == "laser" and not self._laser_beam:
                lf_ranges = np.full((len(live), len(angles)), np.nan)
                lf_ranges[sel] = np.where(finite, rows, np.inf)
                continue
            filters = [team[k] for k in sel]
            if t == "sonar":
                update_beam_batch(filters, rows, angles, cfg["sonar_max_range"], self._cone)
            else:
                update_beam_batch(filters, rows, angles, cfg["laser_max_range"])
        gps_mask = readings.gps_mask.tolist()
        compass_mask = readings.compass_mask.tolist()
        gps = [self._has_gps_l[i] and gps_mask[robots[i]] for i in live]
        compass = [self._has_compass_l[i] and compass_mask[robots[i]] for i in live]
        if lf_ranges is not None or any(gps) or any(compass):
            # every live robot in one pass: one without a scan or a fix keeps its weights
            fixes = self._fixes(live, gps, compass, readings)
            weigh_batch(team, lf_ranges, None if lf_ranges is None else self._angles["laser"],
                        cfg["laser_max_range"], fixes)
        return n_scans

    def _fixes(self, idx: list[int], gps: list[bool], compass: list[bool],
               readings: Readings) -> np.ndarray:
        """:meth:`ParticleFilter.fix_row` of robots ``idx`` (backend indices) for their DGPS
        fixes (where ``gps``) and compass readings (where ``compass``)."""
        rows = []
        std = self.config_fields["compass_std"]
        gps_xy = readings.gps_xy.tolist()
        gps_var = readings.gps_var.tolist()
        heading = readings.compass.tolist()
        for i, has_gps, has_compass in zip(idx, gps, compass, strict=True):
            g = self._robot_ids[i]
            row = [0.0] * 7
            if has_gps:
                (x, y), var = gps_xy[g], gps_var[g]
                if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(var)
                        and var > 0):
                    raise ValueError(f"DGPS fixes must be finite with a positive variance, "
                                     f"got {(x, y)}, {var}")
                ox, oy = self._origins_l[i]
                row[:4] = (1.0, x - ox, y - oy, -0.5 / var)
            if has_compass:
                c = heading[g]
                if not (math.isfinite(c) and std > 0):
                    raise ValueError(f"compass readings must be finite with compass_std > 0, "
                                     f"got {c}, {std}")
                row[4:] = (1.0, c, -0.5 / std**2)
            rows.append(row)
        return np.array(rows).reshape(-1, 7)

    def beam_model(self, i: int) -> tuple[RangeTable, BeamLUT, np.ndarray, float]:
        """What a planner needs to predict local robot ``i``'s scans in the known map.

        Returns its range table (sonar cones included), the tempered per-beam
        log-likelihood table of its beam model, its robot-frame beam angles and
        its maximum range. A likelihood-field laser robot gets the beam model of
        its :class:`MCLConfig` (tables built on first use, then shared).
        """
        t = self._sensor(i)
        sonar = t == "sonar"
        max_range = self.cfg.sonar_max_range if sonar else self.cfg.laser_max_range
        table, lut = self.filters[i].beam_tables(max_range, self._cone if sonar else 0.0)
        return table, lut, self._angles[t], float(max_range)

    # ------------------------------------------------------------------ outputs
    def _summaries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Means, covariances and features of all filters, computed together once per step."""
        if self._summary is None:
            if self.filters:
                self._summary = belief_summaries(self.filters, HIST_CELLS, HIST_CELL,
                                                 HEADING_BINS)
            else:
                self._summary = (np.zeros((0, 3)), np.zeros((0, 3, 3)),
                                 np.zeros((0, self.feature_size), dtype=np.float32))
        return self._summary

    def mean(self) -> np.ndarray:
        """Weighted mean poses ``(k, 3)`` (circular mean heading)."""
        return self._summaries()[0].copy()

    def cov(self) -> np.ndarray:
        """Weighted covariances ``(k, 3, 3)`` (heading deviations wrapped about the mean)."""
        return self._summaries()[1].copy()

    def features(self) -> np.ndarray:
        """Belief embeddings ``(k, 48)`` (layout: :attr:`feature_names`)."""
        return self._summaries()[2].astype(float)

    def beliefs(self) -> Beliefs:
        """Means, covariances and features, and each robot's particle set (on first read)."""
        summary = self._summaries()
        return Beliefs(self.robots, summary[0].copy(), summary[1].copy(),
                       summary[2].astype(float), _ParticleSampler(self, summary))

    def particle_sets(self) -> dict[int, ParticleSet]:
        """Global robot index -> its filter's particles, weights and ESS, now."""
        return {g: ParticleSet(pf.particles, pf.weights, pf.ess)
                for g, pf in zip(self._robot_ids, self.filters, strict=True)}

    def is_current(self, summary: tuple) -> bool:
        """Whether ``summary`` (of :meth:`beliefs`) is of the filters' present state."""
        return self._summary is summary

    def particle_filter(self, i: int) -> ParticleFilter:
        """The particle filter of local robot ``i``."""
        return self.filters[i]

    def extra_info(self, true_poses: np.ndarray) -> dict[int, dict]:
        """``particle_spread`` (weighted mean particle distance from the truth, m),
        ``n_particles``, ``detections_used`` (belief transfers received) and
        ``detection_conflicts`` (detections this robot made or received this episode that
        contradicted a confident detected robot, so were not transferred) per robot."""
        spread = particle_spreads(self.filters, np.asarray(true_poses)[self.robots, :2])
        return {
            g: {"particle_spread": s, "n_particles": pf.n_particles, "detections_used": used,
                "detection_conflicts": c}
            for g, s, pf, used, c in zip(self.robots.tolist(), spread.tolist(), self.filters,
                                         self.transfers_applied.tolist(),
                                         self.detection_conflicts.tolist(), strict=True)
        }


class _ParticleSampler:
    """The particle sets behind one :meth:`MCLBackend.beliefs` record, read on demand
    while the filters have not stepped since (a picklable callable)."""

    def __init__(self, backend: MCLBackend, summary: tuple) -> None:
        self.backend = backend
        self.summary = summary
        self._sets: dict[int, ParticleSet] | None = None  # read once, then kept

    def __call__(self) -> dict[int, ParticleSet]:
        if self._sets is None:
            if not self.backend.is_current(self.summary):
                raise RuntimeError("these beliefs are of an earlier step: the particle sets "
                                   "they summarize are no longer available")
            self._sets = self.backend.particle_sets()
        return self._sets

