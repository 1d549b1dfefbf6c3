"""Scoring motion primitives by expected entropy for ``infogain`` on MCL robots: the belief's
pose hypotheses, the scans each would predict along a primitive, and the expected posterior
entropy over regions (:mod:`policies.scripted.infogain_mcl` has the method and the planner)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl.beam_table import BeamLUT, RangeTable


@dataclass(frozen=True)
class Primitive:
    """A closed-loop motion in the robot frame: turn in place, then drive.

    Attributes:
        turn: rad turned in place first (+ = left).
        rate: rad/s turned while driving.
        speed: fraction of the maximum speed while driving (0 = stand still).
    """

    turn: float = 0.0
    rate: float = 0.0
    speed: float = 1.0


def default_primitives(curve_rate: float = 0.4) -> tuple[Primitive, ...]:
    """Stand, straight, curve left/right, and turn by +-45, +-90, +-135 or 180 deg then drive."""
    out = [Primitive(speed=0.0), Primitive(), Primitive(rate=curve_rate),
           Primitive(rate=-curve_rate)]
    for deg in (45, -45, 90, -90, 135, -135, 180):
        out.append(Primitive(turn=float(np.deg2rad(deg))))
    return tuple(out)


def belief_hypotheses(particles: np.ndarray, weights: np.ndarray, n: int, cell: float = 1.0,
                      heading_bins: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """At most ``n`` pose hypotheses ``(H, 3)`` and their weights ``(H,)`` (summing to 1).

    Particles are binned by position (``cell`` m) and heading (``heading_bins``);
    each bin gives its weighted mean pose (circular mean heading) and weight.
    With more than ``n`` bins, ``n`` draws by systematic sampling (a fixed
    offset: deterministic) pick bins in proportion to weight; a bin drawn ``k``
    times weighs ``k / n``.
    """
    particles = np.asarray(particles, dtype=float)
    weights = np.asarray(weights, dtype=float)
    if particles.ndim != 2 or particles.shape[1] != 3 or len(particles) < 1:
        raise ValueError(f"particles must be (N >= 1, 3), got shape {particles.shape}")
    if weights.shape != (len(particles),) or not np.all(np.isfinite(weights)) or \
            np.any(weights < 0) or not weights.sum() > 0:
        raise ValueError("weights must be finite, >= 0, one per particle and not all zero")
    if n < 1 or heading_bins < 1 or not cell > 0:
        raise ValueError(f"need n >= 1, heading_bins >= 1 and cell > 0, got n={n}, "
                         f"heading_bins={heading_bins}, cell={cell}")
    w = weights / weights.sum()
    ix = np.floor(particles[:, 0] / cell).astype(np.int64)
    iy = np.floor(particles[:, 1] / cell).astype(np.int64)
    ih = np.floor((wrap_angle(particles[:, 2]) + np.pi) / (2 * np.pi) * heading_bins)
    ih = np.clip(ih.astype(np.int64), 0, heading_bins - 1)
    ix -= ix.min()
    iy -= iy.min()
    key = (ix * (iy.max() + 1) + iy) * heading_bins + ih
    uniq, inv = np.unique(key, return_inverse=True)
    m = len(uniq)
    mass = np.bincount(inv, w, m)
    pos = np.stack([np.bincount(inv, w * particles[:, k], m) for k in (0, 1)], 1)
    c = np.bincount(inv, w * np.cos(particles[:, 2]), m)
    s = np.bincount(inv, w * np.sin(particles[:, 2]), m)
    keep = mass > 0
    poses = np.column_stack([pos[keep] / mass[keep, None], np.arctan2(s[keep], c[keep])])
    mass = mass[keep]
    if len(mass) > n:
        cum = np.cumsum(mass)
        cum[-1] = 1.0
        picks = np.searchsorted(cum, (np.arange(n) + 0.5) / n)
        picks, counts = np.unique(picks, return_counts=True)
        poses, mass = poses[picks], counts / n
    return poses, mass / mass.sum()


FRONT = 0.7  # rad: half-width of the sector of the scan checked ahead
SIDE = 1.6  # rad: the side sectors compared to pick the freer side span FRONT..SIDE
AVOID = 1.2  # m: a return nearer than this ahead makes the robot turn in place
TURNED = 0.1  # rad: the in-place turn of a primitive is done within this
SIDE_VEER = 0.1  # rad per step the tracker turns away from a wall close beside


def region_labels(poses: np.ndarray, size: float, headings: int) -> np.ndarray:
    """``(H,)`` labels ``0..G-1`` of the regions (``size`` m squares x ``headings`` sectors)
    that hold ``poses (H, 3)``."""
    ix = np.floor(poses[:, 0] / size).astype(np.int64)
    iy = np.floor(poses[:, 1] / size).astype(np.int64)
    ih = np.floor((wrap_angle(poses[:, 2]) + np.pi) / (2 * np.pi) * headings).astype(np.int64)
    ih = np.clip(ih, 0, headings - 1)
    key = ((ix - ix.min()) * (iy.max() - iy.min() + 1) + iy - iy.min()) * headings + ih
    return np.unique(key, return_inverse=True)[1].ravel()


def scan_sectors(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masks of the beams ahead, on the left and on the right (robot-frame ``angles``)."""
    return (np.abs(angles) <= FRONT, (angles > FRONT) & (angles <= SIDE),
            (angles < -FRONT) & (angles >= -SIDE))


@dataclass(frozen=True)
class ScanModel:
    """One robot's scan prediction model and kinematics (what the scorer needs).

    Attributes:
        table: the map's range table for the robot's beams.
        lut: the filter's tempered beam log-likelihood table.
        angles: robot-frame beam angles.
        scans_per_s: range scans the robot takes per second.
        max_speed: m/s.
        max_turn_rate: rad/s.
    """

    table: RangeTable
    lut: BeamLUT
    angles: np.ndarray
    scans_per_s: float
    max_speed: float
    max_turn_rate: float


class PrimitiveScorer:
    """Scores motion primitives by expected posterior entropy (steps 2-5 of the module doc).

    Args:
        horizon: s of motion simulated per primitive.
        sim_dt: s per simulation step (collision checks).
        scan_every: s between predicted scans (the first at ``scan_every``).
        stop_distance: m: a hypothesis whose way ahead is nearer than this stops.
        collision_cost: nats per unit probability of a collision.
        progress_weight: nats per metre of expected progress (the tie-break).
        progress: ``"displacement"`` (net, from the start to the horizon) or ``"path"``
            (distance driven).
        region: m, the entropy is that of the posterior over regions (squares of this
            size times ``region_headings`` heading sectors holding the hypotheses now),
            not over the hypotheses themselves (0): telling apart two hypotheses of
            one mode, a bin apart, is not localizing.
        region_headings: heading sectors of a region.
        detect_tolerance: m: a detection rules out hypotheses farther than this.
        detect_loglik: log-likelihood drop of a ruled-out hypothesis.
    """

    def __init__(self, horizon: float = 10.0, sim_dt: float = 0.25, scan_every: float = 1.0,
                 stop_distance: float = 0.4, collision_cost: float = 0.3,
                 progress_weight: float = 0.05, detect_tolerance: float = 2.0,
                 detect_loglik: float = 5.0, progress: str = "displacement",
                 region: float = 3.0, region_headings: int = 4) -> None:
        if not (np.isfinite(region) and region >= 0):
            raise ValueError(f"region must be >= 0, got {region!r}")
        if isinstance(region_headings, bool) or not isinstance(region_headings, int) or \
                region_headings < 1:
            raise ValueError(f"region_headings must be a positive integer, "
                             f"got {region_headings!r}")
        self.region, self.region_headings = float(region), region_headings
        if progress not in ("displacement", "path"):
            raise ValueError(f"progress must be 'displacement' or 'path', got {progress!r}")
        self.progress = progress
        for key, value in (("horizon", horizon), ("sim_dt", sim_dt), ("scan_every", scan_every),
                           ("detect_tolerance", detect_tolerance)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be > 0, got {value!r}")
        for key, value in (("stop_distance", stop_distance), ("collision_cost", collision_cost),
                           ("progress_weight", progress_weight),
                           ("detect_loglik", detect_loglik)):
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be >= 0, got {value!r}")
        if scan_every > horizon:
            raise ValueError(f"scan_every ({scan_every}) must not exceed horizon ({horizon})")
        self.horizon, self.sim_dt = float(horizon), float(sim_dt)
        self.scan_every = float(scan_every)
        self.stop_distance, self.collision_cost = float(stop_distance), float(collision_cost)
        self.progress_weight = float(progress_weight)
        self.detect_tolerance, self.detect_loglik = float(detect_tolerance), float(detect_loglik)
        n_sim = int(round(self.horizon / self.sim_dt))
        every = max(1, int(round(self.scan_every / self.sim_dt)))
        self._n_sim = n_sim
        self._scan_steps = np.arange(every, n_sim + 1, every)  # sim steps with a scan

    def simulate(self, model: ScanModel, poses: np.ndarray, primitives: tuple[Primitive, ...]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every hypothesis under every primitive, as the robot would execute it.

        After the in-place turn a hypothesis drives; when its predicted scan
        shows a return nearer than ``AVOID`` ahead it turns in place toward the
        freer side, as the robot's tracker does; a step that would bring it
        within ``stop_distance`` of what is ahead is not taken (a collision:
        it stops there for the rest of the horizon).
        Returns poses at the scan times ``(P, H, K, 3)``, whether each hit a
        wall ``(P, H)`` and how far each got from its start ``(P, H)`` (the net
        displacement: driving in circles is no progress).
        """
        p, h = len(primitives), len(poses)
        dt = self.sim_dt
        ang = np.asarray(model.angles, dtype=float)
        front, lsec, rsec = scan_sectors(ang)
        near = front | lsec | rsec
        ang_near = ang[near]
        front, lsec, rsec = front[near], lsec[near], rsec[near]
        turn = np.array([q.turn for q in primitives])
        rate = np.array([q.rate for q in primitives])
        speed = np.array([q.speed for q in primitives]) * model.max_speed
        x = np.repeat(poses[None, :, 0], p, 0).ravel()
        y = np.repeat(poses[None, :, 1], p, 0).ravel()
        th = np.repeat(poses[None, :, 2], p, 0).ravel()
        left = np.repeat(turn, h)  # rad still to turn in place
        rate_ = np.repeat(rate, h)
        v = np.repeat(speed, h)
        stopped = v <= 0
        blocked = np.zeros(p * h, dtype=bool)
        driven = np.zeros(p * h)
        out = np.empty((len(self._scan_steps), 3, p * h))
        k = 0
        step_turn = model.max_turn_rate * dt
        ox, oy = model.table.origin
        for s in range(1, self._n_sim + 1):
            spin = np.clip(left, -step_turn, step_turn)
            left -= spin
            th = th + spin
            driving = (np.abs(left) < 1e-9) & ~stopped
            if driving.any() and near.any():
                idx = np.flatnonzero(driving)
                scan = model.table.expected((x[idx] - ox).astype(np.float32),
                                            (y[idx] - oy).astype(np.float32),
                                            th[idx].astype(np.float32), ang_near)
                ahead = scan[:, front].min(axis=1) if front.any() else np.full(len(idx), np.inf)
                avoid = ahead < AVOID
                if avoid.any():  # the tracker's reflex: turn in place toward the freer side
                    lmin = scan[:, lsec].min(axis=1) if lsec.any() else np.full(len(idx), np.inf)
                    rmin = scan[:, rsec].min(axis=1) if rsec.any() else np.full(len(idx), np.inf)
                    side = np.where(lmin >= rmin, 1.0, -1.0)
                    a = idx[avoid]
                    th[a] += 0.8 * step_turn * side[avoid]
                step = v[idx] * dt
                hit = ~avoid & (ahead - step < self.stop_distance)
                go = ~avoid & ~hit
                stopped[idx[hit]] = True
                blocked[idx[hit]] = True
                g = idx[go]
                x[g] += step[go] * np.cos(th[g])
                y[g] += step[go] * np.sin(th[g])
                th[g] += rate_[g] * dt
                driven[g] += step[go]
            if k < len(self._scan_steps) and s == self._scan_steps[k]:
                out[k] = x, y, th
                k += 1
        scan_poses = out.reshape(len(self._scan_steps), 3, p, h).transpose(2, 3, 0, 1)
        if self.progress == "displacement":
            moved = np.hypot(x - np.repeat(poses[None, :, 0], p, 0).ravel(),
                             y - np.repeat(poses[None, :, 1], p, 0).ravel())
        else:
            moved = driven
        return scan_poses, blocked.reshape(p, h), moved.reshape(p, h)

    def loglik(self, model: ScanModel, scan_poses: np.ndarray) -> np.ndarray:
        """``(P, H, H)``: log-likelihood of hypothesis ``h'`` (last axis) given the scans
        hypothesis ``h`` (middle axis) would take, summed over the predicted scans."""
        p, h, k, _ = scan_poses.shape
        table, lut = model.table, model.lut
        flat = scan_poses.reshape(-1, 3)
        ox, oy = table.origin
        e = table.expected((flat[:, 0] - ox).astype(np.float32),
                           (flat[:, 1] - oy).astype(np.float32),
                           flat[:, 2].astype(np.float32), model.angles)  # (P*H*K, B)
        rows = lut.rows(e).reshape(p, h, -1)  # measured: the truth's predicted scan
        cols = (e * np.float32(1.0 / lut.step) + np.float32(0.5)).astype(np.intp)
        cols = cols.reshape(p, h, -1)
        ll = np.empty((p, h, h))
        for q in range(p):
            idx = rows[q][:, None, :] + cols[q][None, :, :]
            ll[q] = lut.table.take(idx).sum(axis=2, dtype=np.float64)
        return ll * (model.scans_per_s * self.scan_every)

    def detection_loglik(self, scan_poses: np.ndarray, teammates: np.ndarray,
                         reach: float) -> np.ndarray:
        """``(P, H, H)`` log-likelihood terms of the detections by confident teammates at
        ``teammates (m, 2)`` within ``reach`` m (see the module doc); zeros without any."""
        p, h = scan_poses.shape[:2]
        out = np.zeros((p, h, h))
        if len(teammates) == 0:
            return out
        xy = scan_poses[..., :2]  # (P, H, K, 2)
        d = xy[:, :, :, None, :] - teammates[None, None, None]
        near = (np.hypot(d[..., 0], d[..., 1]) < reach).any(axis=3)  # (P, H, K)
        if not near.any():
            return out
        gap = xy[:, :, None] - xy[:, None, :]  # (P, H, H, K, 2)
        far = np.hypot(gap[..., 0], gap[..., 1]) > self.detect_tolerance
        ruled_out = (near[:, :, None, :] & far).any(axis=3)
        out[ruled_out] = -self.detect_loglik
        return out

    def scores(self, model: ScanModel, poses: np.ndarray, weights: np.ndarray,
               primitives: tuple[Primitive, ...], teammates: np.ndarray | None = None,
               reach: float = 0.0, seek: tuple[np.ndarray, np.ndarray] | None = None
               ) -> dict[str, np.ndarray]:
        """Per primitive: ``score`` (lower is better), ``entropy`` (expected posterior
        entropy, nats), ``collision`` (probability), ``progress`` (expected net
        displacement at the horizon, m) and ``team`` (the teammates' expected entropy
        reduction, nats).

        ``teammates (m, 2)``: confident teammates' positions, whose detections inform
        this robot within ``reach`` m. ``seek = (points (q, 2), nats (q,))``: where
        lost teammates may be and the entropy each would lose if this robot detected
        it there (weighted by how likely it is there); the team term sums those
        within ``reach`` of the path."""
        poses = np.asarray(poses, dtype=float)
        weights = np.asarray(weights, dtype=float)
        if poses.ndim != 2 or poses.shape[1] != 3 or len(poses) < 1:
            raise ValueError(f"poses must be (H >= 1, 3), got shape {poses.shape}")
        if weights.shape != (len(poses),) or not np.isclose(weights.sum(), 1.0) or \
                np.any(weights < 0):
            raise ValueError("weights must be >= 0, one per pose and sum to 1")
        if not primitives:
            raise ValueError("primitives must not be empty")
        scan_poses, blocked, moved = self.simulate(model, poses, primitives)
        ll = self.loglik(model, scan_poses) if model.scans_per_s > 0 else np.zeros(
            (len(primitives), len(poses), len(poses)))
        if teammates is not None and reach > 0:
            ll += self.detection_loglik(scan_poses, np.asarray(teammates, float).reshape(-1, 2),
                                        reach)
        with np.errstate(divide="ignore"):
            logw = np.log(weights)
        post = logw[None, None, :] + ll
        post -= post.max(axis=2, keepdims=True)
        prob = np.exp(post)
        prob /= prob.sum(axis=2, keepdims=True)
        if self.region > 0:  # the posterior of the regions the hypotheses lie in now
            label = region_labels(poses, self.region, self.region_headings)
            onehot = np.zeros((len(poses), label.max() + 1))
            onehot[np.arange(len(poses)), label] = 1.0
            prob = prob @ onehot
        with np.errstate(divide="ignore", invalid="ignore"):
            ent = -np.where(prob > 0, prob * np.log(prob), 0.0).sum(axis=2)  # (P, H)
        entropy = ent @ weights
        collision = blocked.astype(float) @ weights
        progress = moved @ weights
        team = np.zeros(len(primitives))
        if seek is not None and len(seek[0]) and reach > 0:
            points, nats = np.asarray(seek[0], float).reshape(-1, 2), np.asarray(seek[1], float)
            d = scan_poses[..., None, :2] - points  # (P, H, K, q, 2)
            met = (np.hypot(d[..., 0], d[..., 1]) < reach).any(axis=2)  # (P, H, q)
            team = (met.astype(float) @ nats) @ weights
        score = (entropy - team + self.collision_cost * collision
                 - self.progress_weight * progress)
        return {"score": score, "entropy": entropy, "collision": collision,
                "progress": progress, "team": team}
