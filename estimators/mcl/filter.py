"""Monte Carlo localization (Fox, Burgard, Kruppa, Thrun) on an occupancy grid.

:class:`ParticleFilter` keeps one robot's belief over ``(x, y, heading)`` as a
weighted particle set and offers

* an odometry motion model (:meth:`ParticleFilter.predict_odometry`,
  :meth:`ParticleFilter.predict_delta`) with noise proportional to rotation and
  translation (rot1 / trans / rot2 decomposition);
* a likelihood-field laser model (:meth:`ParticleFilter.update_likelihood_field`,
  distance transform of the map) and a beam model with short-reading and
  max-range terms and optional wide cones (:meth:`ParticleFilter.update_beam`,
  for sonar-like sensors);
* low-variance resampling with augmented-MCL random-particle injection
  (slow / fast averages of the measurement likelihood) and optional
  KLD-sampling of the particle count (:meth:`ParticleFilter.resample`);
* uniform initialization over free space for global localization;
* :meth:`ParticleFilter.apply_weight_factors` for external evidence such as
  the detection transfer of :mod:`estimators.mcl.detection_transfer`;
* a fixed-size belief embedding for learning
  (:meth:`ParticleFilter.belief_features`, layout in
  :func:`belief_feature_names`).

One class in one file on purpose (about 630 lines): its methods are the one-robot
API over a :class:`~estimators.mcl.team.ParticleSet` (float32 poses from the centre of
map cell (0, 0), lazily wrapped headings, arrays that may be views of a team's); the
parts that do not need a filter live beside it in :mod:`estimators.mcl`: parameters
(:mod:`~estimators.mcl.config`), motion arithmetic (:mod:`~estimators.mcl.motion`),
sensor tables (:mod:`~estimators.mcl.likelihood_field`,
:mod:`~estimators.mcl.beam_table`), the sampling and weighting passes
(:mod:`~estimators.mcl.sampling`, :mod:`~estimators.mcl.weighting`, a filter alone is
a team of one), the belief embedding (:mod:`~estimators.mcl.features`) and team
batching (:mod:`~estimators.mcl.batch`).

Numerics use numpy/scipy, plus the numba loops there. All randomness comes from the
``numpy.random.Generator`` given to the constructor, so two filters built with
equal seeds and fed equal data produce identical particles.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl._team_kernels import FIX_COLUMNS, predict_blocks
from estimators.mcl.beam_table import (
    BeamLUT,
    RangeTable,
    beam_lut,
    beam_probability,
    range_table,
    scan_loglik,
)
from estimators.mcl.config import MCLConfig, ParticleBelief, ParticleMotionNoise
from estimators.mcl.features import belief_feature_names, belief_features, check_feature_args
from estimators.mcl.inputs import check_scan, fix_parameters
from estimators.mcl.likelihood_field import LF_POWER, LFField, build_lf_field, lf_endpoints
from estimators.mcl.motion import compose_odometry, motion_parameters
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.sampling import (
    kld_sample_bound,
    low_variance_indices,
    resample_team,
    standard_normals,
)
from estimators.mcl.team import ParticleSet, ParticleTeam
from estimators.mcl.weighting import NO_FIELD, weigh_team

__all__ = [
    "MCLConfig",
    "ParticleBelief",
    "ParticleFilter",
    "ParticleMotionNoise",
    "belief_feature_names",
    "compose_odometry",
    "kld_sample_bound",
    "low_variance_indices",
]


class ParticleFilter:
    """Monte Carlo localization of one robot in a known occupancy grid.

    Parameters
    ----------
    grid:
        The map.
    rng:
        Seeded generator; the only source of randomness.
    config:
        Model and algorithm parameters.

    The filter starts with ``config.n_particles`` particles uniformly spread
    over free space (global localization); call :meth:`init_gaussian` for
    position tracking. ``odometer`` accumulates the absolute translation
    reported by odometry (used by the detection lockout). ``particle_set`` is this
    robot's :class:`~estimators.mcl.team.ParticleSet`, whose arrays the team passes of
    :mod:`estimators.mcl.batch` make views of a :class:`~estimators.mcl.team.ParticleTeam`'s.

    Recommended order per step: :meth:`resample_if_needed` (which also injects
    random particles), :meth:`predict_odometry`, the measurement updates,
    detection transfers, then read :meth:`belief`. Resampling first means the
    reported belief is the weighted posterior in which freshly injected
    particles already carry their (usually tiny) weights.
    """

    def __init__(
        self,
        grid: OccupancyGrid,
        rng: np.random.Generator,
        config: MCLConfig | None = None,
    ) -> None:
        if not isinstance(grid, OccupancyGrid):
            raise ValueError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
        self.grid = grid
        self.rng = rng
        self.config = config if config is not None else MCLConfig()
        self.odometer = 0.0
        self.w_slow = 0.0
        self.w_fast = 0.0
        self._lf_cache: dict[float, LFField] = {}
        self._lf_args: dict[float, tuple] = {}  # compiled-kernel arguments by max range
        self._beam_tabs: dict[tuple[float, float], tuple[RangeTable, BeamLUT]] = {}
        self._angles_ok = b""  # bytes of the last beam angles found finite
        self._uniform_w = np.zeros(0)
        # float32 positions relative to the centre of map cell (0, 0) keep ~1e-6 m even
        # for maps at UTM-size coordinates; the likelihood field finds cells by rounding
        res = grid.resolution
        self.particle_set = ParticleSet((grid.origin[0] + 0.5 * res, grid.origin[1] + 0.5 * res))
        self.init_uniform()

    def __getstate__(self) -> dict:
        # The tables are shared per map: rebuilt (from the module caches) instead of copied.
        state = self.__dict__.copy()
        state.update(_beam_tabs={}, _lf_args={})
        return state

    # ---------------------------------------------------------------- state
    @property
    def particles(self) -> np.ndarray:
        """``(N, 3)`` particle poses (float64), headings wrapped to ``[-pi, pi)``.

        A read-only snapshot of the filter's state.
        """
        view = self._world().T
        view.flags.writeable = False
        return view

    def _world(self) -> np.ndarray:
        """``(3, N)`` float64 world poses, headings wrapped to ``[-pi, pi)``.

        Wraps the copy, never the filter's own float32 state: re-wrapping that early
        would round it differently, so reading a belief would change how it evolves.
        """
        ps = self.particle_set
        world = ps.state + ps.origin
        h = world[2]
        # the state's headings drift outside [-pi, pi) for a few steps between wraps (and
        # float32 pi lies just beyond float64 pi): wrap only those (a floating modulo of
        # every heading costs more than the rest of this copy)
        out = (h < -np.pi) | (h >= np.pi)
        if out.any():
            h[out] = wrap_angle(h[out])
        return world

    def _from_world(self, poses: np.ndarray) -> np.ndarray:
        """Internal float32 state of ``(3, N)`` world poses (headings wrapped here)."""
        state = np.empty((3, poses.shape[1]), dtype=np.float32)
        np.subtract(poses, self.particle_set.origin, out=state, casting="same_kind")
        state[2] = wrap_angle(poses[2])
        return state

    @property
    def state_origin(self) -> np.ndarray:
        """World ``(x, y)`` of the internal state's origin (the centre of map cell (0, 0));
        :meth:`fix_row` positions are measured from it."""
        return self.particle_set.origin[:2, 0].copy()

    @property
    def weights(self) -> np.ndarray:
        """``(N,)`` normalized weights (a read-only view)."""
        view = self.particle_set.weights.view()
        view.flags.writeable = False
        return view

    @property
    def n_particles(self) -> int:
        """Current number of particles."""
        return self.particle_set.weights.size

    @property
    def ess(self) -> float:
        """Effective sample size ``1 / sum(w^2)``."""
        return self.particle_set.ess

    @property
    def inject_probability(self) -> float:
        """Fraction of particles the next resampling replaces by uniform ones."""
        cfg = self.config
        p = cfg.random_fraction
        if cfg.augmented and self.w_slow > 0:
            p = max(p, min(cfg.max_inject_fraction, 1.0 - self.w_fast / self.w_slow))
        return float(max(p, 0.0))

    def set_particles(self, particles: np.ndarray, weights: np.ndarray | None = None) -> None:
        """Replace the particle set (``(N, 3)``) and optionally its weights (normalized here)."""
        particles = np.asarray(particles, dtype=float)
        if particles.ndim != 2 or particles.shape[1] != 3 or particles.shape[0] < 1:
            raise ValueError(f"particles must have shape (N>=1, 3), got {particles.shape}")
        if not np.all(np.isfinite(particles)):
            raise ValueError("particles must be finite")
        n = particles.shape[0]
        if weights is None:
            w = np.full(n, 1.0 / n)
        else:
            w = np.asarray(weights, dtype=float)
            if w.shape != (n,):
                raise ValueError(f"weights must have shape ({n},), got {w.shape}")
            total = w.sum()
            if not np.isfinite(total) or total <= 0 or w.min() < 0:
                raise ValueError(f"weights must be non-negative with a positive finite sum, "
                                 f"got sum={total}")
            w = w / total
        self.particle_set.replace_state(self._from_world(particles.T))
        self.particle_set.weights = w

    def _uniform_poses(self, n: int) -> np.ndarray:
        """``(3, n)`` internal state of poses drawn uniformly over free space."""
        xy = self.grid.sample_free(n, self.rng)
        th = self.rng.uniform(-np.pi, np.pi, size=n)
        return self._from_world(np.vstack([xy.T, th]))

    def init_uniform(self, n: int | None = None) -> None:
        """Spread ``n`` (default ``config.n_particles``) particles uniformly over free space."""
        n = self.config.n_particles if n is None else int(n)
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        self.particle_set.replace_state(self._uniform_poses(n))
        self.particle_set.weights = np.full(n, 1.0 / n)
        self.w_slow = self.w_fast = 0.0

    def init_gaussian(self, mean: np.ndarray, cov: np.ndarray, n: int | None = None) -> None:
        """Draw ``n`` particles from a Gaussian ``(mean (3,), cov (3, 3))`` (position tracking)."""
        n = self.config.n_particles if n is None else int(n)
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        if mean.shape != (3,) or not np.all(np.isfinite(mean)):
            raise ValueError(f"mean must be 3 finite numbers, got {mean}")
        if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
            raise ValueError(f"cov must be a finite 3x3 matrix, got shape {cov.shape}")
        if not np.allclose(cov, cov.T) or np.linalg.eigvalsh(cov).min() < -1e-12:
            raise ValueError(f"cov must be symmetric positive semi-definite, got {cov.tolist()}")
        draws = self.rng.multivariate_normal(mean, cov, size=n, method="eigh")
        self.particle_set.replace_state(self._from_world(draws.T))
        self.particle_set.weights = np.full(n, 1.0 / n)
        self.w_slow = self.w_fast = 0.0

    # --------------------------------------------------------------- motion
    def predict_odometry(self, v: float, w: float, dt: float) -> None:
        """Move particles by a unicycle odometry reading: speed ``v``, turn rate ``w``, ``dt``."""
        v, w, dt = float(v), float(w), float(dt)
        if not (math.isfinite(v) and math.isfinite(w) and math.isfinite(dt)):
            raise ValueError(f"odometry must be finite, got v={v}, w={w}, dt={dt}")
        if dt < 0:
            raise ValueError(f"dt must be >= 0, got {dt}")
        dth = w * dt
        if abs(dth) > 1e-9:
            radius = v / w
            dx = radius * math.sin(dth)
            dy = radius * (1.0 - math.cos(dth))
        else:
            dx, dy = v * dt, 0.0
        self._predict(dx, dy, dth)  # finite: no need to check again

    def predict_odometry_sequence(self, v: np.ndarray, w: np.ndarray, dt: float) -> None:
        """One prediction for several odometry sub-steps (see :func:`compose_odometry`)."""
        self.predict_delta(compose_odometry(v, w, dt))

    def predict_delta(self, delta: np.ndarray | tuple[float, float, float]) -> None:
        """Move particles by a relative motion ``(dx, dy, dheading)`` in the previous robot frame.

        Decomposed into rot1 / trans / rot2 (reverse driving gives a negative
        translation, not a half-turn) and perturbed per :class:`ParticleMotionNoise`.
        """
        try:
            dx, dy, dth = map(float, delta)
        except (TypeError, ValueError) as err:
            raise ValueError(f"delta must be 3 numbers, got {delta!r}") from err
        if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dth)):
            raise ValueError(f"delta must be finite, got {delta!r}")
        self._predict(dx, dy, dth)

    def _predict(self, dx: float, dy: float, dth: float) -> None:
        """:meth:`predict_delta` for a checked, finite motion."""
        ps = self.particle_set
        params = np.array([self.motion_draw(dx, dy, dth)], dtype=np.float32)
        z = standard_normals(self.rng, np.empty(3 * ps.weights.size, dtype=np.float32))
        predict_blocks(ps.flat_state(), z, params, np.array([z.size // 3]))
        ps.after_motion()

    def motion_draw(self, dx: float, dy: float, dth: float) -> tuple[float, ...]:
        """The motion's ``rot1, trans, rot2`` and their noise standard deviations
        (:class:`ParticleMotionNoise`), the parameters of one motion update (its noise:
        ``3 N`` standard normals drawn next from this filter's generator); adds the
        translation to :attr:`odometer`."""
        params = motion_parameters(dx, dy, dth, self.config.motion)
        self.odometer += abs(params[1])
        return params

    # ---------------------------------------------------------- perception
    def lf_field(self, max_range: float) -> LFField:
        """The likelihood-field tables for ``max_range`` (:func:`build_lf_field`; cached here
        and shared through the grid by every filter with the same map and model)."""
        key = float(max_range)
        lf = self._lf_cache.get(key)
        if lf is not None:
            return lf
        cfg = self.config
        # Shared through the grid: all robots using this map and model share one table.
        shared_key = ("lf_table", key, cfg.lf_sigma, cfg.lf_z_hit, cfg.lf_z_rand, cfg.lf_max_dist,
                      cfg.likelihood_exponent, cfg.occupied_loglik)

        lf = self.grid.memo(shared_key, lambda: build_lf_field(self.grid, cfg, key))
        self._lf_cache[key] = lf
        return lf

    def _position_penalty(self) -> np.ndarray:
        """``occupied_loglik`` for particles in occupied cells or outside the map, else 0."""
        free = self.grid.is_free(self._world()[:2].T)
        return np.where(free, 0.0, self.config.occupied_loglik)

    def update_likelihood_field(
        self, ranges: np.ndarray, angles: np.ndarray, max_range: float
    ) -> float:
        """Weight particles by the likelihood-field laser model; returns the scan's log evidence.

        ``ranges`` and robot-frame beam ``angles`` are ``(B,)``; readings at or
        beyond ``max_range`` (including ``inf``) carry no endpoint and are
        skipped. Beam endpoints are precomputed in the robot frame (in cell
        units); one compiled pass moves them to every particle, reads the field
        there and the position penalty at the particle's own cell, and weights
        (:func:`estimators.mcl.weighting.weigh_team`). Returns
        ``log sum_i w_i p(z | x_i)`` with the tempered likelihood and the
        position penalty included.
        """
        ranges, angles, max_range, hi, self._angles_ok = check_scan(ranges, angles, max_range,
                                                                    self._angles_ok)
        lf = self.lf_field(max_range)
        if hi >= max_range:
            keep = ranges < max_range
            ranges, angles = ranges[keep], angles[keep]
        nb = ranges.size
        ux, uy = lf_endpoints(lf, ranges, angles)
        return self._weigh_self(np.zeros(FIX_COLUMNS), nb, None, nb * lf.lmax, nb,
                                self.lf_kernel_args(max_range), ux, uy)

    def _weigh_self(self, fix: np.ndarray, nb: int, loglik: np.ndarray | None,
                    offset: float = 0.0, n_beams: int = 0, lf_args: tuple = NO_FIELD,
                    ux: np.ndarray | None = None, uy: np.ndarray | None = None) -> float:
        """:func:`estimators.mcl.weighting.weigh_team` of this filter alone: a scan
        of ``nb`` beams (-1: none) scored before (``loglik``) or by the likelihood field,
        and the fixes ``fix``. Returns the scan's log evidence."""
        w = self.particle_set.weights
        n = w.size
        scored = loglik is not None
        return float(weigh_team(
            ParticleTeam.alone(self), w, fix.reshape(1, -1),
            np.array([nb]), loglik if scored else np.empty(n), scored, np.array([offset]),
            np.array([n_beams * self.config.likelihood_exponent]), lf_args,
            None if ux is None else ux.reshape(1, -1), None if uy is None else uy.reshape(1, -1),
            float(LF_POWER))[0])

    def expected_ranges(
        self, angles: np.ndarray, max_range: float, cone_half_width: float = 0.0
    ) -> np.ndarray:
        """Ray-cast ranges ``(N, B)`` each particle expects for robot-frame beam ``angles``.

        With ``cone_half_width`` > 0 each beam is the nearest of
        ``config.beam_rays_per_cone`` rays spread over the cone. With
        ``config.beam_lookup_bins`` the rays come from the grid's range table.
        """
        angles = np.asarray(angles, dtype=float).ravel()
        if not np.isfinite(cone_half_width) or cone_half_width < 0:
            raise ValueError(f"cone_half_width must be finite and >= 0, got {cone_half_width}")
        if self.config.beam_lookup_bins:
            table = self.beam_tables(max_range, cone_half_width)[0]
            st = self.particle_set.state
            return table.expected(st[0], st[1], st[2], angles).astype(float)
        k = self.config.beam_rays_per_cone if cone_half_width > 0 else 1
        offsets = np.linspace(-cone_half_width, cone_half_width, k) if k > 1 else np.zeros(1)
        st = self._world()
        world = st[2][:, None, None] + angles[None, :, None] + offsets[None, None, :]
        rays = self.grid.cast_rays(st[:2].T[:, None, None, :], world, max_range)
        return rays.min(axis=2)

    def beam_tables(self, max_range: float, cone_half_width: float = 0.0
                    ) -> tuple[RangeTable, BeamLUT]:
        """The shared range table and beam-likelihood table of this map and model.

        Built on first use and cached per map (see :mod:`estimators.mcl.beam_table`).
        """
        key = (float(max_range), float(cone_half_width))
        tables = self._beam_tabs.get(key)
        if tables is None:
            cfg = self.config
            table = range_table(self.grid, max_range, cfg.beam_lookup_bins or 256,
                                cone_half_width, cfg.beam_rays_per_cone)
            lut = beam_lut(max_range, cfg.beam_sigma, cfg.beam_z_hit, cfg.beam_z_short,
                           cfg.beam_z_max, cfg.beam_z_rand, cfg.beam_lambda_short,
                           cfg.likelihood_exponent)
            tables = self._beam_tabs[key] = (table, lut)
        return tables

    def cached_tables(self) -> tuple[list[tuple[RangeTable, BeamLUT]], list[LFField]]:
        """The beam-model tables and likelihood fields this filter has built or looked up
        so far (shared per map; for memory accounting)."""
        return list(self._beam_tabs.values()), list(self._lf_cache.values())

    def update_beam(
        self,
        ranges: np.ndarray,
        angles: np.ndarray,
        max_range: float,
        cone_half_width: float = 0.0,
    ) -> float:
        """Weight particles by the beam model (hit / short / max / random mixture).

        Suited to sonar-like sensors with few beams and wide cones: expected
        ranges come from ray casting in the map (:meth:`expected_ranges`).
        Max-range readings are scored by the ``beam_z_max`` term. Returns the
        scan's log evidence like :meth:`update_likelihood_field`.
        """
        ranges, angles, max_range, _, self._angles_ok = check_scan(ranges, angles, max_range,
                                                                   self._angles_ok)
        cfg = self.config
        if ranges.size == 0:
            return self._weigh_self(np.zeros(FIX_COLUMNS), 0, self._position_penalty())
        if cfg.beam_lookup_bins:
            if not np.isfinite(cone_half_width) or cone_half_width < 0:
                raise ValueError(f"cone_half_width must be finite and >= 0, "
                                 f"got {cone_half_width}")
            table, lut = self.beam_tables(max_range, cone_half_width)
            loglik = scan_loglik(table, lut, self.particle_set.flat_state(), angles,
                                 lut.rows(ranges)[None, :], np.array([self.n_particles]),
                                 cfg.occupied_loglik)
            return self._weigh_self(np.zeros(FIX_COLUMNS), ranges.size, loglik,
                                    n_beams=ranges.size)
        zexp = self.expected_ranges(angles, max_range, cone_half_width)
        z = np.minimum(ranges, max_range)[None, :]
        p = beam_probability(z, zexp, max_range, cfg.beam_sigma, cfg.beam_z_hit, cfg.beam_z_short,
                             cfg.beam_z_max, cfg.beam_z_rand, cfg.beam_lambda_short)
        loglik = cfg.likelihood_exponent * np.log(p).sum(axis=1) + self._position_penalty()
        return self._weigh_self(np.zeros(FIX_COLUMNS), ranges.size, loglik, n_beams=ranges.size)

    def track_evidence(self, log_evidence: float, n_eff_beams: float) -> None:
        """Update the augmented-MCL slow / fast averages of the per-beam evidence."""
        if n_eff_beams > 0:
            cfg = self.config
            w_avg = math.exp(log_evidence / n_eff_beams)
            if self.w_slow == 0.0:
                self.w_slow = self.w_fast = w_avg
            else:
                self.w_slow += cfg.alpha_slow * (w_avg - self.w_slow)
                self.w_fast += cfg.alpha_fast * (w_avg - self.w_fast)

    def apply_weight_factors(self, factors: np.ndarray) -> None:
        """Multiply the weights by non-negative ``factors`` ``(N,)`` and renormalize.

        Used for external evidence (robot detections). If every product is
        zero the weights are left unchanged (the evidence is treated as
        uninformative) rather than producing NaN.
        """
        f = np.asarray(factors, dtype=float)
        ps = self.particle_set
        if f.shape != ps.weights.shape:
            raise ValueError(f"factors must have shape {ps.weights.shape}, got {f.shape}")
        if not np.all(np.isfinite(f)) or f.min(initial=0.0) < 0:
            raise ValueError("factors must be finite and non-negative")
        w = ps.weights * f
        total = w.sum()
        if total > 0 and np.isfinite(total):
            ps.weights = w / total

    def update_fix(
        self,
        xy: np.ndarray | None = None,
        xy_var: float = 1.0,
        heading: float | None = None,
        heading_std: float = 1.0,
    ) -> None:
        """Weight by a position fix and/or a heading fix (Gaussian likelihoods).

        A position ``xy`` with isotropic variance ``xy_var`` (m^2) multiplies each
        weight by ``exp(-|p - xy|^2 / (2 xy_var)) + 1e-12``; a heading (rad) with
        standard deviation ``heading_std`` by ``exp(-e^2 / (2 heading_std^2)) + 1e-12``
        with ``e`` the wrapped difference (the floors keep a wrong fix from zeroing
        every weight).
        """
        fix = self.fix_row(xy, xy_var, heading, heading_std)
        if fix[0] or fix[4]:
            self._weigh_self(fix, -1, None)

    def fix_row(
        self,
        xy: np.ndarray | None = None,
        xy_var: float = 1.0,
        heading: float | None = None,
        heading_std: float = 1.0,
    ) -> np.ndarray:
        """The checked parameters of :meth:`update_fix` as the compiled update reads them:
        ``[gps?, x, y, -0.5 / xy_var, compass?, heading, -0.5 / heading_std**2]``
        (positions in state coordinates)."""
        return fix_parameters(self.particle_set.origin, xy, xy_var, heading, heading_std)

    def lf_kernel_args(self, max_range: float | None) -> tuple:
        """The likelihood field's arguments of the compiled weighting
        (:func:`~estimators.mcl.weighting.weigh_team`); placeholders for ``max_range=None``
        (no scan)."""
        if max_range is None:
            return NO_FIELD
        lf = self.lf_field(max_range)
        args = self._lf_args.get(float(max_range))
        if args is None:
            args = self._lf_args[float(max_range)] = (
                lf.table, lf.nxp, lf.offset, np.float32(lf.pad), np.float32(lf.inv_res),
                lf.lo[0, 0], lf.lo[1, 0], lf.hi[0, 0], lf.hi[1, 0])
        return args

    # ----------------------------------------------------------- resampling
    def resample(self) -> None:
        """Low-variance resampling with augmented-MCL injection and optional KLD sampling.

        A fraction :attr:`inject_probability` (in expectation) of the new set is
        drawn uniformly over free space; the rest by low-variance resampling.
        With ``config.adaptive`` the new size is chosen by KLD sampling between
        ``n_min`` and ``n_max``: ``n_max`` particles are drawn by low-variance
        resampling and shuffled, and the shortest prefix whose size reaches the
        KLD bound for the number of histogram bins (``kld_bin``) it occupies is
        kept; otherwise the size is kept. Random draws, in order: adaptive: the
        resampling offset, ``n_max`` 64-bit words for the shuffle, the injected count
        (binomial); fixed size:
        the injected count, the offset; then the injected positions
        (:meth:`OccupancyGrid.sample_free`) and headings.
        (:func:`estimators.mcl.sampling.resample_team` does it for a team.)
        """
        resample_team(ParticleTeam.alone(self), self.particle_set.weights, [True])

    def uniform_weights(self, n: int) -> np.ndarray:
        """Weights ``1 / n`` (a shared read-only array: weights are never changed in place)."""
        w = self._uniform_w
        if w.size != n:
            w = self._uniform_w = np.full(n, 1.0 / n)
            w.flags.writeable = False
        return w

    def resample_if_needed(self) -> bool:
        """Resample when ESS < ``resample_ess_fraction * N`` or injection is due; report it."""
        cfg = self.config
        if self.ess < cfg.resample_ess_fraction * self.particle_set.weights.size or (
            self.inject_probability > 0
        ):
            self.resample()
            return True
        return False

    # --------------------------------------------------------------- output
    def mean_pose(self) -> np.ndarray:
        """Weighted mean ``(x, y, heading)`` with the circular mean heading."""
        w = self.particle_set.weights
        st = self._world()
        x = float(np.dot(w, st[0]))
        y = float(np.dot(w, st[1]))
        h = float(np.arctan2(np.dot(w, np.sin(st[2])), np.dot(w, np.cos(st[2]))))
        return np.array([x, y, h])

    def belief(self) -> ParticleBelief:
        """Mean, weighted covariance (heading wrapped about the mean), particles, weights."""
        particles = self.particles.copy()
        mean = self.mean_pose()
        w = self.particle_set.weights
        d = particles.T - mean[:, None]
        d[2] = wrap_angle(d[2])
        cov = (d * w) @ d.T
        cov = 0.5 * (cov + cov.T)
        return ParticleBelief(mean=mean, cov=cov, particles=particles, weights=w.copy())

    def position_std(self) -> float:
        """RMS per-axis weighted standard deviation (m) of the particles' positions."""
        w = self.particle_set.weights
        st = self.particle_set.state
        total = 0.0
        for row in (st[0], st[1]):
            x = row.astype(np.float64)
            mean = float(w @ x)
            x -= mean
            x *= x
            total += float(w @ x)
        return math.sqrt(0.5 * max(total, 0.0))

    def particle_spread(self, true_pose: np.ndarray) -> float:
        """Weighted mean distance (m) of the particles from the true position (Fox et al.)."""
        p = np.asarray(true_pose, dtype=float)
        if p.shape not in ((2,), (3,)) or not np.all(np.isfinite(p)):
            raise ValueError(f"true_pose must be 2 or 3 finite numbers, got {true_pose}")
        st = self._world()
        dist = np.hypot(st[0] - p[0], st[1] - p[1])
        return float(np.dot(self.particle_set.weights, dist))


    def belief_features(
        self,
        hist_cells: int = 5,
        cell_size: float = 1.0,
        heading_bins: int = 8,
    ) -> np.ndarray:
        """Fixed-size ``float32`` embedding of the belief; layout in :func:`belief_feature_names`.

        The egocentric histogram is a ``hist_cells x hist_cells`` grid of
        ``cell_size`` m cells centred on the mean pose and aligned with the mean
        heading. The length does not depend on the particle count
        (:func:`estimators.mcl.features.belief_features`).
        """
        check_feature_args(hist_cells, cell_size, heading_bins)
        st = self._world()
        mean = self.mean_pose()
        cfg = self.config
        count_fraction = self.n_particles / cfg.n_max if cfg.adaptive else 1.0
        return belief_features(self.particle_set.weights, st, mean, self.ess / self.n_particles,
                               count_fraction, self.grid.bounds, hist_cells, cell_size,
                               heading_bins)
