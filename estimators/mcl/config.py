"""Parameters and result type of the particle filter (:mod:`estimators.mcl.filter`).

:class:`ParticleMotionNoise` (odometry noise of the particle motion model; not
the EKF's :class:`estimators.team_ekf.MotionNoise`), :class:`MCLConfig` (every
model and algorithm parameter, checked at construction) and
:class:`ParticleBelief` (the summary :meth:`ParticleFilter.belief` returns).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MCLConfig", "ParticleBelief", "ParticleMotionNoise"]


@dataclass(frozen=True)
class ParticleMotionNoise:
    """Odometry noise, as standard deviations proportional to the motion.

    For a motion decomposed into ``rot1`` (turn towards the new position),
    ``trans`` and ``rot2`` (final turn)::

        std(rot1)  = rot_rot * |rot1| + rot_trans * |trans| + min_heading
        std(trans) = trans_trans * |trans| + trans_rot * (|rot1| + |rot2|) + min_xy
        std(rot2)  = rot_rot * |rot2| + rot_trans * |trans| + min_heading

    ``min_xy`` (m) and ``min_heading`` (rad) are per-prediction floors
    ("roughening"): they keep particle diversity while the robot stands still
    and let a set that collapsed slightly off the truth drift back to it.
    They are per call, so scale them with the prediction rate.
    """

    rot_rot: float = 0.05
    rot_trans: float = 0.02
    trans_trans: float = 0.05
    trans_rot: float = 0.01
    min_xy: float = 0.02
    min_heading: float = 0.01

    def __post_init__(self) -> None:
        for name in ("rot_rot", "rot_trans", "trans_trans", "trans_rot", "min_xy", "min_heading"):
            val = getattr(self, name)
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"ParticleMotionNoise.{name} must be finite and >= 0, got {val}")


@dataclass(frozen=True)
class MCLConfig:
    """Parameters of :class:`ParticleFilter` (defaults suit a 2D laser robot).

    Likelihood field: each beam endpoint scores
    ``lf_z_hit * N(d; 0, lf_sigma) + lf_z_rand / max_range`` where ``d`` is the
    distance from the endpoint to the nearest obstacle (clipped at
    ``lf_max_dist``); max-range readings are skipped.

    Beam model: ``beam_z_hit`` Gaussian around the ray-cast range (std
    ``beam_sigma``, truncated to ``[0, max_range]``), ``beam_z_short``
    exponential short readings (rate ``beam_lambda_short``), ``beam_z_max``
    point mass at max range, ``beam_z_rand`` uniform. A beam with a cone
    (``cone_half_width`` > 0) expects the nearest of ``beam_rays_per_cone``
    rays spread over the cone. ``beam_lookup_bins`` > 0 replaces ray casting
    by lookups in a :class:`~estimators.mcl.beam_table.RangeTable` (that many
    heading bins; ranges from the cell centre corrected to first order for
    the particle's exact position and heading) and the model's terms by a
    :class:`~estimators.mcl.beam_table.BeamLUT` over ranges quantized to
    ``max_range / 511``: both built once per map and shared, then an update
    costs two gathers per particle and beam instead of a ray cast.

    ``likelihood_exponent`` multiplies every scan log-likelihood (< 1 tempers
    the overconfidence of treating beams as independent). Particles whose
    position is occupied or outside the map get ``occupied_loglik`` added.

    Resampling happens in :meth:`ParticleFilter.resample_if_needed` when the
    effective sample size drops below ``resample_ess_fraction * N`` or the
    augmented-MCL injection probability is positive. Augmented MCL tracks the
    per-beam geometric-mean likelihood with rates ``alpha_slow`` < ``alpha_fast``
    and injects uniform particles with probability
    ``max(random_fraction, min(max_inject_fraction, 1 - w_fast / w_slow))``.
    The constant ``random_fraction`` is Fox et al.'s "small number of uniformly
    distributed samples after each estimation step": it is what lets global
    localization escape a wrong mode that a too-early collapse locked in (the
    slow/fast averages cannot notice a consistently mediocre match).

    KLD sampling (``adaptive=True``) chooses the particle count between
    ``n_min`` and ``n_max`` so that, with probability ``1 - kld_delta``, the
    K-L divergence between the sample-based and the true posterior stays below
    ``kld_epsilon``, using histogram bins of size ``kld_bin`` (m, m, rad).
    """

    n_particles: int = 1000
    motion: ParticleMotionNoise = field(default_factory=ParticleMotionNoise)
    lf_sigma: float = 0.2
    lf_z_hit: float = 0.9
    lf_z_rand: float = 0.1
    lf_max_dist: float = 2.0
    beam_sigma: float = 0.3
    beam_z_hit: float = 0.7
    beam_z_short: float = 0.1
    beam_z_max: float = 0.1
    beam_z_rand: float = 0.1
    beam_lambda_short: float = 0.5
    beam_rays_per_cone: int = 3
    beam_lookup_bins: int = 0
    likelihood_exponent: float = 1.0
    occupied_loglik: float = -10.0
    resample_ess_fraction: float = 0.5
    augmented: bool = True
    alpha_slow: float = 0.01
    alpha_fast: float = 0.2
    max_inject_fraction: float = 0.3
    random_fraction: float = 0.03
    adaptive: bool = False
    n_min: int = 100
    n_max: int = 5000
    kld_epsilon: float = 0.05
    kld_delta: float = 0.01
    kld_bin: tuple[float, float, float] = (0.5, 0.5, float(np.deg2rad(10.0)))

    def __post_init__(self) -> None:
        positive = (
            "lf_sigma", "lf_max_dist", "beam_sigma", "beam_lambda_short",
            "likelihood_exponent", "kld_epsilon",
        )
        for name in positive:
            val = getattr(self, name)
            if not np.isfinite(val) or val <= 0:
                raise ValueError(f"MCLConfig.{name} must be finite and > 0, got {val}")
        nonneg = (
            "lf_z_hit", "lf_z_rand", "beam_z_hit", "beam_z_short", "beam_z_max",
            "beam_z_rand", "alpha_slow", "alpha_fast",
        )
        for name in nonneg:
            val = getattr(self, name)
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"MCLConfig.{name} must be finite and >= 0, got {val}")
        if self.lf_z_rand <= 0:
            raise ValueError(f"MCLConfig.lf_z_rand must be > 0 (keeps weights finite), "
                             f"got {self.lf_z_rand}")
        if self.beam_z_rand <= 0:
            raise ValueError(f"MCLConfig.beam_z_rand must be > 0 (keeps weights finite), "
                             f"got {self.beam_z_rand}")
        for name in ("max_inject_fraction", "random_fraction", "resample_ess_fraction"):
            val = getattr(self, name)
            if not 0.0 <= val <= 1.0:
                raise ValueError(f"MCLConfig.{name} must be in [0, 1], got {val}")
        if not 0.0 < self.kld_delta < 1.0:
            raise ValueError(f"MCLConfig.kld_delta must be in (0, 1), got {self.kld_delta}")
        if not np.isfinite(self.occupied_loglik) or self.occupied_loglik > 0:
            raise ValueError(f"MCLConfig.occupied_loglik must be finite and <= 0, "
                             f"got {self.occupied_loglik}")
        if self.n_particles < 1:
            raise ValueError(f"MCLConfig.n_particles must be >= 1, got {self.n_particles}")
        if not 1 <= self.n_min <= self.n_max:
            raise ValueError(f"MCLConfig needs 1 <= n_min <= n_max, got n_min={self.n_min}, "
                             f"n_max={self.n_max}")
        if self.beam_lookup_bins != 0 and self.beam_lookup_bins < 4:
            raise ValueError(f"MCLConfig.beam_lookup_bins must be 0 (off) or >= 4, "
                             f"got {self.beam_lookup_bins}")
        if self.beam_rays_per_cone < 1:
            raise ValueError(f"MCLConfig.beam_rays_per_cone must be >= 1, "
                             f"got {self.beam_rays_per_cone}")
        if len(self.kld_bin) != 3 or not all(np.isfinite(b) and b > 0 for b in self.kld_bin):
            raise ValueError(f"MCLConfig.kld_bin must be three positive sizes, got {self.kld_bin}")


@dataclass(frozen=True)
class ParticleBelief:
    """Summary of a particle belief.

    ``mean`` is ``(x, y, heading)`` with the circular mean heading; ``cov`` is
    the weighted ``3x3`` covariance with heading deviations wrapped around the
    mean; ``particles`` ``(N, 3)`` and ``weights`` ``(N,)`` (summing to 1) are
    copies of the filter's state.
    """

    mean: np.ndarray
    cov: np.ndarray
    particles: np.ndarray
    weights: np.ndarray
