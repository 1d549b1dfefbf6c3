"""Is a robot detection consistent with both robots' beliefs? And what to do when it is not.

Fox et al.'s transfer (Eq. 10/13, :mod:`estimators.mcl.detection_transfer`) trusts
the observer: the detected robot's belief is multiplied by the density the
observer's belief predicts for it. When both beliefs are confident and
disagree about where the pair is, at least one of them is wrong, and the
product then follows whichever stray particles of the detected robot happen
to lie where the observer says (a few uniform random particles always do):
a correctly localized robot detected by a teammate locked onto a rotated copy
of a symmetric map is thrown off.

The measure. The detection's likelihood under both beliefs taken together,

    L = integral integral p(z | x_m, x_n) Bel_m(x_m) Bel_n(x_n) dx_m dx_n,

written in the detected robot's pose space (``k(x_n | x_m, z)``: the density
of ``n``'s pose that ``m`` at ``x_m`` and the detection ``z`` imply, the one
:func:`~estimators.mcl.detection_transfer.sample_detected_poses` draws from), is
compared with the same integral for a detected robot that knows nothing
(uniform over the map's box of volume ``V``, where it equals ``1 / V``). The
ratio is a Bayes factor,

    B = V * E_{x_m ~ Bel_m, x_n ~ Bel_n}[k(x_n | x_m, z)],

with a reading that needs no tuning per map: ``B`` about 1 or more when
either belief is uninformative or the two agree (it grows with how sharply
they agree), and ``B`` much less than 1 when the detected robot's belief puts
less mass where the observer says it is than a belief that knew nothing
would. :func:`detection_bayes_factor` evaluates it exactly over given
particle pairs (the kernel in closed form: Gaussian range, bearing and
relative heading noise, over the polar Jacobian ``r``);
:func:`tree_bayes_factor` reads it from the density tree the transfer grows
anyway (``V`` times the tree's density averaged over all of the detected
robot's particles: no extra sampling, so it is what the env step uses).

The decision (:func:`assess_detection`). A detected robot is *confident* when
its main mode (the particles within ``mode_radius`` of the weighted
coordinate-wise median) holds at least ``confident_mass`` of its weight. The
detection *conflicts* with a confident robot when ``B < min_bayes_factor``
(both cannot be right; the false-positive mixture of the transfer then
already leaves the belief almost unchanged) or when the transfer would move
the bulk of its main mode's mass elsewhere (the observer agrees only with a
few stray particles). On a conflict the transfer is not applied: a confident
robot is never moved toward a contradicting observer. Two beliefs that are
not confident are multiplied as in the paper: in the hexagon, where a sonar
robot keeps three copies of its pose and a laser robot two, that product is
what localizes the team.

Widening (:func:`widen`, with clouds placed by :func:`move_rigidly`). A
single conflict cannot say which of the two is wrong:
a robot locked onto a rotated copy of a symmetric map is as sharp as a
correctly localized one, and both have fitted every scan so far. So each
confident party (position spread under ``RESET_STD`` in the backend: a
multi-modal or lost robot is never a source) makes sure the other keeps a
minority hypothesis, ``widen_mass`` of its weight, where it claims the other
is, in place of the other's least likely particles. Each keeps its own mode
alive: a correct robot stays localized (its mean spread grows by
``widen_mass`` times the distance to the other claim), a wrong one stops
being confident, and its own scans decide between the two where the map
stops being symmetric. Topping up, not adding, keeps repeated conflicts from
eroding a correct belief.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl._keeper_kernels import weighted_median
from estimators.mcl.beam_table import BeamLUT, RangeTable, scan_loglik

__all__ = [
    "ConsistencyConfig",
    "DetectionAssessment",
    "assess_detection",
    "backtrack",
    "detection_bayes_factor",
    "main_mode",
    "move_rigidly",
    "pose_estimate",
    "scan_loglik_along",
    "target_pose_density",
    "tree_bayes_factor",
    "widen",
]

_LOG_2PI = math.log(2 * math.pi)


@dataclass(frozen=True)
class ConsistencyConfig:
    """Parameters of the detection consistency check (see the module docstring).

    ``min_bayes_factor``: a detection whose Bayes factor is below this conflicts with a
    confident detected robot. ``mode_radius`` (m): particles this close to the weighted
    median position form the main mode. ``confident_mass``: a robot whose main mode holds
    at least this much weight is confident. ``move_fraction``: a transfer that would leave
    less than this fraction of the main mode's weight in it would move the robot (a
    conflict). ``widen_mass``: the weight a widened robot keeps where the other claims it is.
    """

    min_bayes_factor: float = 0.1
    mode_radius: float = 2.0
    confident_mass: float = 0.6
    move_fraction: float = 0.5
    widen_mass: float = 0.05

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_bayes_factor) and self.min_bayes_factor >= 0):
            raise ValueError(f"min_bayes_factor must be finite and >= 0, "
                             f"got {self.min_bayes_factor}")
        if not (math.isfinite(self.mode_radius) and self.mode_radius > 0):
            raise ValueError(f"mode_radius must be > 0, got {self.mode_radius}")
        for name in ("confident_mass", "move_fraction"):
            val = getattr(self, name)
            if not 0.0 < val <= 1.0:
                raise ValueError(f"{name} must be in (0, 1], got {val}")
        if not 0.0 <= self.widen_mass < 0.5:
            raise ValueError(f"widen_mass must be in [0, 0.5), got {self.widen_mass}")


def target_pose_density(
    observer_poses: np.ndarray, target_poses: np.ndarray, z: np.ndarray, std: np.ndarray,
) -> np.ndarray:
    """``k(x_n | x_m, z)`` for every pair: ``(K_m, K_n)`` densities of the target's pose.

    ``z`` is ``(range, bearing)`` or ``(range, bearing, orientation)`` (the target's
    heading relative to the observer's) with standard deviations ``std``; the density is
    over ``(x, y)`` or ``(x, y, heading)`` accordingly: Gaussian in the measured
    quantities over the polar Jacobian (the distance, floored at a tenth of the range
    standard deviation).
    """
    om = np.asarray(observer_poses, dtype=float)
    tn = np.asarray(target_poses, dtype=float)
    z = np.asarray(z, dtype=float)
    std = np.asarray(std, dtype=float)
    if z.shape not in ((2,), (3,)) or std.shape != z.shape:
        raise ValueError(f"z and std must both be (2,) or (3,), got {z.shape} and {std.shape}")
    if not (np.all(np.isfinite(std)) and np.all(std > 0)):
        raise ValueError(f"std must be finite and > 0, got {std.tolist()}")
    dx = tn[None, :, 0] - om[:, None, 0]
    dy = tn[None, :, 1] - om[:, None, 1]
    r = np.hypot(dx, dy)
    b = wrap_angle(np.arctan2(dy, dx) - om[:, None, 2] - z[1])
    logk = (-0.5 * ((r - z[0]) / std[0]) ** 2 - 0.5 * (b / std[1]) ** 2
            - _LOG_2PI - math.log(std[0] * std[1]) - np.log(np.maximum(r, 0.1 * std[0])))
    if z.shape == (3,):
        o = wrap_angle(tn[None, :, 2] - om[:, None, 2] - z[2])
        logk += -0.5 * (o / std[2]) ** 2 - 0.5 * _LOG_2PI - math.log(std[2])
    return np.exp(logk)


def detection_bayes_factor(
    observer_poses: np.ndarray, target_poses: np.ndarray, z: np.ndarray, std: np.ndarray,
    volume: float, observer_weights: np.ndarray | None = None,
    target_weights: np.ndarray | None = None, chunk: int = 256,
) -> float:
    """``V * E[k(x_n | x_m, z)]`` over every pair of the given particles (weighted).

    ``volume`` is that of the box a know-nothing belief would be uniform over (area, times
    ``2 pi`` when ``z`` has an orientation). Pass subsamples (equal weights) for speed.
    """
    if not (math.isfinite(volume) and volume > 0):
        raise ValueError(f"volume must be finite and > 0, got {volume}")
    om = np.asarray(observer_poses, dtype=float)
    tn = np.asarray(target_poses, dtype=float)
    wm = _weights(observer_weights, len(om), "observer_weights")
    wn = _weights(target_weights, len(tn), "target_weights")
    total = 0.0
    for s in range(0, len(om), chunk):
        k = target_pose_density(om[s:s + chunk], tn, z, std)
        total += float(wm[s:s + chunk] @ k @ wn)
    return volume * total


def tree_bayes_factor(tree_pdf: np.ndarray, target_weights: np.ndarray, volume: float) -> float:
    """The Bayes factor from the transfer's density tree: ``V * sum_i w_i tree_pdf(x_i)``."""
    return float(volume * np.dot(np.asarray(target_weights, dtype=float),
                                 np.asarray(tree_pdf, dtype=float)))


def _weights(w: np.ndarray | None, n: int, name: str) -> np.ndarray:
    if n < 1:
        raise ValueError(f"{name}: need at least one particle")
    if w is None:
        return np.full(n, 1.0 / n)
    w = np.asarray(w, dtype=float)
    total = w.sum()
    if w.shape != (n,) or not np.isfinite(total) or total <= 0 or w.min() < 0:
        raise ValueError(f"{name} must be ({n},) non-negative with a positive sum")
    return w / total


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    value, ok = weighted_median(np.ascontiguousarray(x), np.ascontiguousarray(w))
    if ok:  # selection, no sort (compiled); else the sort decides rounding-close cases
        return value
    order = np.argsort(x)
    cum = np.cumsum(w[order])
    return float(x[order[min(int(np.searchsorted(cum, 0.5 * cum[-1])), len(x) - 1)]])


def main_mode(xy: np.ndarray, weights: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The main mode of a particle set: its centre (the weighted coordinate-wise median
    position, which lies in the heaviest cluster whenever one holds most of the weight;
    the weighted mean when the whole set lies within a quarter of ``radius`` of it, one
    standard deviation, where the two agree and the mean costs no sort) and the mask of
    the particles within ``radius`` of it."""
    xy = np.asarray(xy, dtype=float)
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    mean = w @ xy
    spread2 = float(w @ ((xy[:, 0] - mean[0]) ** 2 + (xy[:, 1] - mean[1]) ** 2))
    if spread2 <= (0.25 * radius) ** 2:
        centre = mean
    else:
        centre = np.array([_weighted_median(xy[:, 0], w), _weighted_median(xy[:, 1], w)])
    d2 = (xy[:, 0] - centre[0]) ** 2 + (xy[:, 1] - centre[1]) ** 2
    return centre, d2 <= radius * radius


@dataclass(frozen=True)
class DetectionAssessment:
    """What :func:`assess_detection` found: the Bayes factor, whether the detected robot is
    confident, its main mode's weight before and after the would-be transfer, and whether
    the detection conflicts with it."""

    bayes_factor: float
    confident: bool
    mode_mass: float
    mode_mass_after: float
    conflict: bool


def assess_detection(
    target_xy: np.ndarray, target_weights: np.ndarray, factors: np.ndarray,
    bayes_factor: float, config: ConsistencyConfig, hypotheses: np.ndarray | None = None,
) -> DetectionAssessment:
    """Decide whether a transfer with weight ``factors`` conflicts with the detected robot.

    ``hypotheses``: a mask of the target's particles that stand for where it may be
    (its top mode and the symmetric copies of it that it keeps), used in place of its
    main mode: a robot sure to be on one of a few copies of the map is confident about
    that set, and a detection that picks one of them moves no mass out of it, while one
    that puts it nowhere near any of them (a false positive) does.
    """
    w = np.asarray(target_weights, dtype=float)
    if hypotheses is None:
        _, mode = main_mode(target_xy, w, config.mode_radius)
    else:
        mode = np.asarray(hypotheses, dtype=bool)
        if mode.shape != w.shape:
            raise ValueError(f"hypotheses must be a mask of shape {w.shape}, got {mode.shape}")
    mass = float(w[mode].sum())
    post = w * np.asarray(factors, dtype=float)
    total = float(post.sum())
    after = float(post[mode].sum() / total) if total > 0 and math.isfinite(total) else mass
    confident = mass >= config.confident_mass
    conflict = confident and (bayes_factor < config.min_bayes_factor
                              or after < config.move_fraction * mass)
    return DetectionAssessment(float(bayes_factor), confident, mass, after, conflict)


def widen(
    particles: np.ndarray, weights: np.ndarray, claimed: np.ndarray, mass: float,
    radius: float, rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Top a belief up to ``mass`` near the poses another robot claims for it.

    ``claimed`` ``(K, 3)`` are poses the other robot's belief and the detection imply
    (already restricted to free space by the caller). If less than ``mass`` of the weight
    lies within ``radius`` of their median position, the missing weight is given to
    ``round(mass * N)`` of them (drawn at random), placed in the slots of the least likely
    particles outside that region; the other weights are scaled to keep the total at 1.
    Returns the new particles, weights and how many were placed (0: nothing to do).
    """
    parts = np.array(particles, dtype=float)
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    claimed = np.asarray(claimed, dtype=float)
    n = len(w)
    if len(claimed) == 0 or mass <= 0:
        return parts, w, 0
    centre, near = main_mode(claimed[:, :2], np.full(len(claimed), 1.0 / len(claimed)), radius)
    d2 = (parts[:, 0] - centre[0]) ** 2 + (parts[:, 1] - centre[1]) ** 2
    here = d2 <= radius * radius
    have = float(w[here].sum())
    if have >= mass:
        return parts, w, 0
    k = min(max(1, int(round(mass * n))), int((~here).sum()))
    if k < 1:
        return parts, w, 0
    outside = np.nonzero(~here)[0]
    slots = outside[np.argsort(w[outside], kind="stable")[:k]]
    pool = claimed[near] if near.any() else claimed
    parts[slots] = pool[rng.integers(0, len(pool), size=k)]
    keep = ~here
    keep[slots] = False
    rest = float(w[keep].sum())
    new_w = w.copy()  # the particles already near the claim keep their weight
    new_w[keep] *= (1.0 - mass) / rest if rest > 0 else 0.0
    new_w[slots] = (mass - have) / k
    return parts, new_w / new_w.sum(), k


def pose_estimate(poses: np.ndarray, weights: np.ndarray, radius: float) -> np.ndarray:
    """The pose of a belief's main mode (:func:`main_mode`): its centre and the circular
    mean heading of its particles."""
    poses = np.asarray(poses, dtype=float)
    w = np.asarray(weights, dtype=float)
    centre, mode = main_mode(poses[:, :2], w, radius)
    wm = w[mode] if mode.any() else w
    h = poses[mode, 2] if mode.any() else poses[:, 2]
    return np.array([centre[0], centre[1], math.atan2(wm @ np.sin(h), wm @ np.cos(h))])


def backtrack(pose: np.ndarray, deltas: np.ndarray) -> np.ndarray:
    """Past poses ``(K, 3)`` of a robot that is at ``pose`` now and moved by the odometry
    ``deltas`` ``(K, 3)`` (oldest first; each ``(dx, dy, dheading)`` in the robot frame at
    its start): row ``k`` is the pose at the end of motion ``k``, the last row ``pose``.
    For poses ``(P, 3)`` the result is ``(P, K, 3)``."""
    pose = np.asarray(pose, dtype=float)
    many = pose.ndim == 2
    p = pose.reshape(-1, 3)
    d = np.asarray(deltas, dtype=float).reshape(-1, 3)
    k = len(d)
    out = np.empty((len(p), k, 3))
    if k:
        # heading before motion j: the current heading less every turn from j on
        turn_from = np.cumsum(d[::-1, 2])[::-1]
        before = p[:, 2:3] - turn_from[None, :]
        c, s = np.cos(before), np.sin(before)
        u = np.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1]], axis=-1)
        # position at the end of motion k: now less every displacement after it
        after = np.cumsum(u[:, ::-1], axis=1)[:, ::-1]
        after = np.concatenate([after[:, 1:], np.zeros((len(p), 1, 2))], axis=1)
        out[..., :2] = p[:, None, :2] - after
        out[..., 2] = wrap_angle(np.concatenate([before[:, 1:], p[:, 2:3]], axis=1))
    return out if many else out[0]


def scan_loglik_along(
    table: RangeTable, lut: BeamLUT, origin: np.ndarray, angles: np.ndarray,
    poses: np.ndarray, scans: np.ndarray, occupied_loglik: float,
) -> np.ndarray | float:
    """Sum of the beam-model log-likelihoods of ``scans`` ``(K, B)`` (NaN: no reading)
    taken at ``poses`` ``(K, 3)`` (world frame; ``origin`` is the table's cell (0, 0)
    centre), with ``occupied_loglik`` for each pose in an occupied cell or off the map.
    For trajectories ``(P, K, 3)`` one sum per trajectory ``(P,)``."""
    poses = np.asarray(poses, dtype=float)
    many = poses.ndim == 3
    traj = poses.reshape(-1, poses.shape[-2], 3)
    n, k = traj.shape[:2]
    if k == 0:
        return np.zeros(n) if many else 0.0
    flat = traj.reshape(-1, 3)
    # one pose per segment of the compiled beam pass (its x, y, heading in a row)
    poses32 = np.empty((n * k, 3), dtype=np.float32)
    poses32[:, 0] = flat[:, 0] - origin[0]
    poses32[:, 1] = flat[:, 1] - origin[1]
    poses32[:, 2] = flat[:, 2]
    rows = np.broadcast_to(lut.rows(scans)[None], (n, k, len(angles))).reshape(-1, len(angles))
    ll = scan_loglik(table, lut, poses32.reshape(-1), angles, rows,
                     np.arange(1, n * k + 1, dtype=np.intp), occupied_loglik)
    total = ll.reshape(n, k).sum(axis=1)
    return total if many else float(total[0])


def move_rigidly(poses: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """``poses`` ``(N, 3)`` moved by the rigid motion (turn and shift) that takes pose
    ``src`` to pose ``dst``: a particle cloud carried to another hypothesis keeps the shape
    the robot's own scans gave it."""
    poses = np.asarray(poses, dtype=float)
    turn = float(dst[2] - src[2])
    c, s = math.cos(turn), math.sin(turn)
    d = poses[:, :2] - np.asarray(src[:2], dtype=float)
    out = np.empty_like(poses)
    out[:, 0] = dst[0] + c * d[:, 0] - s * d[:, 1]
    out[:, 1] = dst[1] + s * d[:, 0] + c * d[:, 1]
    out[:, 2] = wrap_angle(poses[:, 2] + turn)
    return out
