"""Collaborative MCL: belief transfer when one robot detects another (Fox et al., Eq. 10 / 13).

When robot ``m`` detects robot ``n`` with a relative measurement ``r_m``
(range, bearing and optionally the relative orientation of ``n``), ``n``'s
belief is multiplied by ``m``'s belief about where ``n`` is::

    Bel_n(l) <- Bel_n(l) * integral P(L_n = l | L_m = l', r_m) Bel_m(l') dl'

Implementation (as in the paper): draw poses of ``m`` from its particles,
push each through the detection model (measurement noise sampled from the
reported standard deviations, :func:`sample_detected_poses`), grow a
:class:`~estimators.mcl.density_tree.DensityTree` from those samples over the
map's box (``(x, y)``, or ``(x, y, heading)`` when the orientation is
measured), and multiply every particle of ``n`` by the tree's density there.
The symmetric update of ``m`` from ``n``'s belief is optional
(:func:`sample_observer_poses` inverts the model; it uses ``n``'s belief from
*before* ``n`` was updated, so no evidence flows back to its source).

Guards against double counting (the paper's two rules):

1. Negative sightings (a robot *not* seeing another) are ignored: only
   positive detections are processed; records flagged ``detected=False`` or
   without a target are skipped.
2. After ``m`` used a detection of ``n``, further detections of ``n`` by ``m``
   are ignored until ``m``'s odometer has advanced ``lockout_distance``
   (2.5 m in the paper). With the symmetric update the reverse pair
   ``(n, m)`` is locked as well, keyed to ``n``'s odometer.

Tempering (``TransferConfig.exponent`` < 1, not in the paper). Relative
detections are blind to a rotation of the whole team: if every robot's belief
is turned about the centre of a symmetric room by the same angle, every
detection fits as well as before; only each robot's own scans can rule such a
frame out. The lockout still lets a robot be detected every few seconds when
detectors see all round and robots share one room, and each transfer
re-imports beliefs that earlier transfers already shaped (the factorial
double counting the paper's two rules only limit). Untempered, those repeated
factors outweigh scans that are themselves tempered against their own
overconfidence, and a team settles on whichever frame it first agrees on.
Raising the factor to a power below 1 makes a transfer count as a fraction of
an independent observation, as the scans' ``likelihood_exponent`` does; a
single transfer then shifts weight between modes less, and several transfers
between robots of different sensor types are needed to settle a symmetry.

False positives. The detection model is the paper's mixture: with
probability ``false_positive_prob`` a reported detection is spurious and
carries no information, so the factor applied to ``n``'s particles is
``(1 - p_fp) * tree_pdf(l) + p_fp / V`` with ``V`` the volume of the tree's
domain (a uniform density over the same box). Consequences:

* every factor is at least ``p_fp / V > 0``: a false positive can never zero
  all weights, produce NaN, or empty the particle set;
* if ``n`` is already well localized and the detection disagrees with it,
  ``tree_pdf`` is ~0 at all of ``n``'s particles and the update leaves ``n``'s
  belief (almost) unchanged: the posterior probability that the detection
  was false, ``p_fp / V / ((1 - p_fp) E[tree_pdf] + p_fp / V)``, is reported as
  ``false_positive_posterior`` and is then close to 1;
* if ``n`` is lost, a false positive does pull its belief towards the wrong
  place; augmented-MCL injection in :class:`~estimators.mcl.filter.ParticleFilter`
  (the slow/fast likelihood averages) is what recovers from that, as from
  any other localization failure. With ``p_fp = 0`` and a tree that is zero
  at every particle, the weights are left unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from estimators.geometry import compose_relative, wrap_angle
from estimators.mcl.density_tree import DensityTree
from estimators.mcl.detection_consistency import (
    ConsistencyConfig,
    assess_detection,
    tree_bayes_factor,
)
from estimators.mcl.filter import ParticleFilter, low_variance_indices

__all__ = [
    "DetectionLockout",
    "DetectionTransfer",
    "RobotDetection",
    "TransferConfig",
    "TransferResult",
    "detection_from_measurement",
    "detection_weight_factors",
    "sample_detected_poses",
    "sample_observer_poses",
]


@dataclass(frozen=True)
class RobotDetection:
    """One positive detection of robot ``target`` by robot ``observer``.

    ``range`` (m) and ``bearing`` (rad, in the observer's frame) locate the
    target; ``orientation`` is the target's heading relative to the
    observer's (rad) or ``None`` when not measured. ``*_std`` are the
    measurement standard deviations. ``detected=False`` marks a negative
    sighting, which the transfer ignores.
    """

    observer: Hashable
    target: Hashable
    range: float
    bearing: float
    range_std: float
    bearing_std: float
    orientation: float | None = None
    orientation_std: float | None = None
    detected: bool = True

    def __post_init__(self) -> None:
        if not self.detected:
            return  # negative sightings carry no measurement to validate
        if self.observer == self.target:
            raise ValueError(f"a robot cannot detect itself (observer = target = {self.observer})")
        for name in ("range", "bearing", "range_std", "bearing_std"):
            val = getattr(self, name)
            if not math.isfinite(val):
                raise ValueError(f"RobotDetection.{name} must be finite, got {val}")
        if self.range < 0:
            raise ValueError(f"RobotDetection.range must be >= 0, got {self.range}")
        if self.range_std <= 0 or self.bearing_std <= 0:
            raise ValueError(f"detection std devs must be > 0, got range_std={self.range_std}, "
                             f"bearing_std={self.bearing_std}")
        if self.orientation is not None:
            if not math.isfinite(self.orientation):
                raise ValueError(f"RobotDetection.orientation must be finite, "
                                 f"got {self.orientation}")
            std = self.orientation_std
            if std is None or not math.isfinite(std) or std <= 0:
                raise ValueError(f"orientation_std must be > 0 when orientation is given, "
                                 f"got {std}")


def detection_from_measurement(
    observer: Hashable, target: Hashable, z: np.ndarray, cov: np.ndarray
) -> RobotDetection:
    """Build a :class:`RobotDetection` from ``z = (range, bearing, orientation)`` and its
    ``3x3`` noise covariance (standard deviations from the diagonal; correlations dropped).
    """
    z = np.asarray(z, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if z.shape != (3,) or cov.shape != (3, 3):
        raise ValueError(f"z must be (3,) and cov (3, 3), got {z.shape} and {cov.shape}")
    var = np.diag(cov)
    if not np.all(np.isfinite(var)) or np.any(var <= 0):
        raise ValueError(f"detection variances (range_std, bearing_std, orientation_std "
                         f"squared) must be finite and > 0, got {var.tolist()}")
    std = np.sqrt(var)
    return RobotDetection(
        observer=observer, target=target, range=float(z[0]), bearing=float(z[1]),
        range_std=float(std[0]), bearing_std=float(std[1]), orientation=float(z[2]),
        orientation_std=float(std[2]),
    )


@dataclass(frozen=True)
class TransferConfig:
    """Parameters of :class:`DetectionTransfer`.

    ``n_samples`` poses of the observer are pushed through the detection
    model to grow the density tree (leaf size ``leaf_size``, default
    ``sqrt(n_samples)``); ``heading_scale`` (m per rad) weighs the heading
    axis when the tree picks its longest dimension. ``symmetric`` also
    updates the observer from the target's belief. ``exponent`` tempers the
    detection likelihood: the factor applied to the target's weights is
    ``((1 - p_fp) tree_pdf + p_fp / V) ** exponent`` (1, the default, is the
    paper's Eq. 14; see the module docstring for when less is needed). ``consistency``
    (``None``, the paper's transfer, by default) checks every detection against both
    beliefs first and skips the transfer when it conflicts with a confident detected
    robot (:mod:`estimators.mcl.detection_consistency`).
    """

    lockout_distance: float = 2.5
    false_positive_prob: float = 0.05
    n_samples: int = 1000
    leaf_size: int | None = None
    heading_scale: float = 1.0
    symmetric: bool = False
    exponent: float = 1.0
    consistency: ConsistencyConfig | None = None

    def __post_init__(self) -> None:
        if not math.isfinite(self.lockout_distance) or self.lockout_distance < 0:
            raise ValueError(f"lockout_distance must be finite and >= 0, "
                             f"got {self.lockout_distance}")
        if not 0.0 <= self.false_positive_prob < 1.0:
            raise ValueError(f"false_positive_prob must be in [0, 1), "
                             f"got {self.false_positive_prob}")
        if self.n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {self.n_samples}")
        if not math.isfinite(self.heading_scale) or self.heading_scale <= 0:
            raise ValueError(f"heading_scale must be > 0, got {self.heading_scale}")
        if not math.isfinite(self.exponent) or not 0 < self.exponent <= 1:
            raise ValueError(f"exponent must be in (0, 1], got {self.exponent}")


@dataclass(frozen=True)
class TransferResult:
    """Outcome of one detection: whether it was used, why not, and diagnostics.

    ``reason`` is ``"applied"``, ``"negative"`` (not a positive sighting),
    ``"locked"`` (within the lockout distance), ``"unknown_robot"``,
    ``"outside_map"`` (no sample of the target fell inside the map) or
    ``"conflict"`` (the consistency check found the detection contradicts a
    confident target; the lockout is recorded as for an applied one).
    ``false_positive_posterior`` is the probability, after the update, that
    the detection was spurious (``None`` when not applied); ``bayes_factor``
    the detection's consistency with both beliefs
    (:func:`estimators.mcl.detection_consistency.tree_bayes_factor`; ``None`` when
    no tree was grown); ``tree`` the density of the target's pose the target was
    multiplied by (:meth:`DetectionTransfer.mixture_factors` of it gives the factor
    at any pose; ``None`` when not applied).
    """

    applied: bool
    reason: str
    false_positive_posterior: float | None = None
    symmetric_applied: bool = False
    bayes_factor: float | None = None
    tree: DensityTree | None = None


def _draw_particles(pf: ParticleFilter, n: int, rng: np.random.Generator) -> np.ndarray:
    idx = low_variance_indices(pf.weights, n, rng)
    return pf.particles[rng.permutation(idx)]


def sample_detected_poses(
    observer_poses: np.ndarray, det: RobotDetection, rng: np.random.Generator
) -> np.ndarray:
    """Target poses ``(K, 3)`` implied by observer poses ``(K, 3)`` and a noisy detection.

    Each observer pose gets its own draw of range, bearing (and orientation)
    from the measurement's Gaussian noise. Without a measured orientation the
    returned heading column is meaningless (the caller uses ``x, y`` only).
    """
    poses = np.asarray(observer_poses, dtype=float)
    k = poses.shape[0]
    rbo = np.empty((k, 3))
    rbo[:, 0] = np.abs(det.range + det.range_std * rng.standard_normal(k))
    rbo[:, 1] = det.bearing + det.bearing_std * rng.standard_normal(k)
    if det.orientation is not None:
        rbo[:, 2] = det.orientation + det.orientation_std * rng.standard_normal(k)
    else:
        rbo[:, 2] = 0.0
    return compose_relative(poses, rbo)


def sample_observer_poses(
    target_poses: np.ndarray, det: RobotDetection, rng: np.random.Generator
) -> np.ndarray:
    """Observer poses ``(K, 3)`` implied by target poses ``(K, 3)`` (the inverse model).

    With a measured orientation: observer heading ``= target heading - o`` and
    position ``= target - r (cos, sin)(heading_m + bearing)``. Without it the
    direction from observer to target is unknown, so it is drawn uniformly:
    the observer lies on a ring of radius ``r`` around the target with a
    heading consistent with the bearing.
    """
    poses = np.asarray(target_poses, dtype=float)
    k = poses.shape[0]
    r = np.abs(det.range + det.range_std * rng.standard_normal(k))
    b = det.bearing + det.bearing_std * rng.standard_normal(k)
    if det.orientation is not None:
        o = det.orientation + det.orientation_std * rng.standard_normal(k)
        heading_m = poses[:, 2] - o
        phi = heading_m + b
    else:
        phi = rng.uniform(-np.pi, np.pi, size=k)
        heading_m = phi - b
    out = np.empty((k, 3))
    out[:, 0] = poses[:, 0] - r * np.cos(phi)
    out[:, 1] = poses[:, 1] - r * np.sin(phi)
    out[:, 2] = wrap_angle(heading_m)
    return out


def detection_weight_factors(
    tree: DensityTree, points: np.ndarray, false_positive_prob: float
) -> tuple[np.ndarray, float]:
    """Mixture factors ``(1 - p) tree.pdf + p / V`` at ``points``, and the uniform ``1 / V``."""
    if not 0.0 <= false_positive_prob < 1.0:
        raise ValueError(f"false_positive_prob must be in [0, 1), got {false_positive_prob}")
    uniform = 1.0 / tree.volume
    factors = (1.0 - false_positive_prob) * tree.pdf(points) + false_positive_prob * uniform
    return factors, uniform


@dataclass
class DetectionLockout:
    """Bookkeeping of the "travel before re-using a robot" rule, per (observer, target) pair.

    ``odometer`` values are the observer's cumulative distance travelled
    (:attr:`ParticleFilter.odometer`).
    """

    distance: float = 2.5
    _last: dict[tuple[Hashable, Hashable], float] = field(default_factory=dict, repr=False)

    def is_locked(self, observer: Hashable, target: Hashable, odometer: float) -> bool:
        """True while ``observer`` moved less than ``distance`` since it last used ``target``."""
        last = self._last.get((observer, target))
        return last is not None and odometer - last < self.distance

    def record(self, observer: Hashable, target: Hashable, odometer: float) -> None:
        """Note that ``observer`` used a detection of ``target`` at ``odometer``."""
        self._last[(observer, target)] = float(odometer)

    def reset(self) -> None:
        """Forget all past detections (new episode)."""
        self._last.clear()


class DetectionTransfer:
    """Applies Eq. 10 / 13 between the particle filters of a team, with the paper's guards."""

    def __init__(self, config: TransferConfig | None = None) -> None:
        self.config = config if config is not None else TransferConfig()
        self.lockout = DetectionLockout(self.config.lockout_distance)

    def reset(self) -> None:
        """Clear the lockout memory (call at the start of an episode)."""
        self.lockout.reset()

    def _tree(self, samples: np.ndarray, pf: ParticleFilter, use_heading: bool
              ) -> DensityTree | None:
        xmin, ymin, xmax, ymax = pf.grid.bounds
        inside = (
            (samples[:, 0] >= xmin) & (samples[:, 0] < xmax)
            & (samples[:, 1] >= ymin) & (samples[:, 1] < ymax)
        )
        if not inside.any():
            return None
        cfg = self.config
        if use_heading:
            pts = samples[inside]
            low = np.array([xmin, ymin, -np.pi])
            # headings lie in [-pi, pi]: wrap_angle may return +pi itself
            high = np.array([xmax, ymax, np.nextafter(np.pi, np.inf)])
            scale = np.array([1.0, 1.0, cfg.heading_scale])
        else:
            pts = samples[inside, :2]
            low, high, scale = np.array([xmin, ymin]), np.array([xmax, ymax]), None
        return DensityTree(pts, low=low, high=high, scale=scale, leaf_size=cfg.leaf_size)

    def _factors(self, pf: ParticleFilter, tree: DensityTree, use_heading: bool
                 ) -> tuple[np.ndarray, np.ndarray, float]:
        """The tree's density at ``pf``'s particles, the (tempered) mixture factors and
        the false-positive posterior."""
        p_fp = self.config.false_positive_prob
        parts = pf.particles if use_heading else pf.particles[:, :2]
        pdf = tree.pdf(parts)
        uniform = 1.0 / tree.volume
        factors = self._mixture(pdf, uniform)
        expected_tree = float(np.dot(pf.weights, pdf))
        denom = (1.0 - p_fp) * expected_tree + p_fp * uniform
        posterior_fp = p_fp * uniform / denom if denom > 0 else 1.0
        return pdf, factors, float(posterior_fp)

    def _mixture(self, pdf: np.ndarray, uniform: float) -> np.ndarray:
        p_fp = self.config.false_positive_prob
        factors = (1.0 - p_fp) * pdf + p_fp * uniform
        if self.config.exponent != 1.0:
            factors = factors ** self.config.exponent
        return factors

    def mixture_factors(self, tree: DensityTree, poses: np.ndarray) -> np.ndarray:
        """The factor a transfer with ``tree`` multiplies a particle at each of ``poses``
        by: ``((1 - p_fp) tree_pdf + p_fp / V) ** exponent`` (``poses`` ``(N, 2)`` or, for a
        tree over headings too, ``(N, 3)``)."""
        return self._mixture(tree.pdf(np.asarray(poses, dtype=float)), 1.0 / tree.volume)

    def _reweight(self, pf: ParticleFilter, tree: DensityTree, use_heading: bool) -> float:
        """Multiply ``pf``'s weights by the mixture factors; return the false-positive posterior."""
        _, factors, posterior_fp = self._factors(pf, tree, use_heading)
        pf.apply_weight_factors(factors)
        return posterior_fp

    def apply(
        self,
        det: RobotDetection,
        observer_pf: ParticleFilter,
        target_pf: ParticleFilter,
        rng: np.random.Generator,
        check: bool = True,
        hypotheses: np.ndarray | None = None,
    ) -> TransferResult:
        """Use one detection: reweight the target's particles (and the observer's if symmetric).

        Returns why it was ignored when a guard applies. The filters are not
        resampled here; their next resampling step picks the new weights up.
        ``check=False`` skips the consistency check (the caller knows the detection
        picks a hypothesis the target holds, not one it has ruled out); ``hypotheses``, a
        mask of the target's particles, is the set the check weighs in place of its main
        mode (:func:`~estimators.mcl.detection_consistency.assess_detection`).
        """
        if not getattr(det, "detected", True) or det.target is None:
            return TransferResult(False, "negative")
        cfg = self.config
        if self.lockout.is_locked(det.observer, det.target, observer_pf.odometer):
            return TransferResult(False, "locked")
        use_heading = det.orientation is not None
        # Sample both directions before changing either belief.
        obs_draw = _draw_particles(observer_pf, cfg.n_samples, rng)
        target_samples = sample_detected_poses(obs_draw, det, rng)
        observer_samples = None
        if cfg.symmetric:
            tgt_draw = _draw_particles(target_pf, cfg.n_samples, rng)
            observer_samples = sample_observer_poses(tgt_draw, det, rng)
        tree = self._tree(target_samples, target_pf, use_heading)
        if tree is None:
            return TransferResult(False, "outside_map")
        pdf, factors, posterior_fp = self._factors(target_pf, tree, use_heading)
        bayes = tree_bayes_factor(pdf, target_pf.weights, tree.volume)
        self.lockout.record(det.observer, det.target, observer_pf.odometer)
        if cfg.consistency is not None and check:
            check = assess_detection(target_pf.particles[:, :2], target_pf.weights, factors,
                                     bayes, cfg.consistency, hypotheses)
            if check.conflict:
                return TransferResult(False, "conflict", posterior_fp, bayes_factor=bayes)
        target_pf.apply_weight_factors(factors)
        sym = False
        if observer_samples is not None:
            # the observer's heading is always constrained by the inverse model
            tree_m = self._tree(observer_samples, observer_pf, True)
            if tree_m is not None:
                self._reweight(observer_pf, tree_m, True)
                self.lockout.record(det.target, det.observer, target_pf.odometer)
                sym = True
        return TransferResult(True, "applied", posterior_fp, sym, bayes, tree)

    def apply_all(
        self,
        detections: Iterable[RobotDetection],
        filters: Mapping[Hashable, ParticleFilter],
        rng: np.random.Generator,
    ) -> list[TransferResult]:
        """Apply detections in order; robots missing from ``filters`` are reported, not raised."""
        results = []
        for det in detections:
            if not getattr(det, "detected", True) or det.target is None:
                results.append(TransferResult(False, "negative"))
            elif det.observer not in filters or det.target not in filters:
                results.append(TransferResult(False, "unknown_robot"))
            else:
                results.append(self.apply(det, filters[det.observer], filters[det.target], rng))
        return results
