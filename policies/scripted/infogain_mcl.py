"""``infogain`` for particle-filter (MCL) robots: expected entropy reduction over motion primitives.

Active Markov localization (Fox, Burgard and Thrun 1998) chooses the action
whose expected posterior entropy over poses is least. Here, every
``replan_every`` env steps and for each live MCL robot:

1. **Hypotheses.** The robot's particles are binned (``cell`` m x ``cell`` m x
   ``heading_bins`` headings); each bin's weighted mean pose and summed weight
   is one pose hypothesis. With more bins than ``n_hypotheses``, that many are
   drawn by deterministic systematic sampling in proportion to weight (their
   weights are the draw counts): the hypotheses follow the belief's modes.
2. **Motion.** Each candidate primitive is a closed-loop behaviour in the
   robot's own frame (the robot does not know its world heading when its
   belief has several modes): turn in place by ``turn`` rad, then drive at
   ``speed`` x maximum speed while turning at ``rate`` rad/s, for ``horizon``
   seconds. Every hypothesis executes it in the known map (steps of
   ``sim_dt``) as the robot would: when its predicted scan shows a return
   nearer than ``AVOID`` ahead it turns in place toward the freer side (the
   tracker's reflex); a step that would bring it within ``stop_distance`` of
   what is ahead is not taken: it stops there for the rest of the horizon and
   counts as a collision.
3. **Predicted scans.** Every ``scan_every`` seconds along the way each
   hypothesis's scan is predicted from the robot's range table (the filter's
   own tables: :meth:`coop_loc_env.mcl_backend.MCLBackend.beam_model`).
4. **Expected entropy.** For each hypothesis ``h`` taken as the truth, its
   predicted (noise-free) scans are scored against every hypothesis ``h'``
   with the filter's tempered beam model (its range noise widened to
   ``plan_sigma``, as hypotheses are bin means; tempered like the filter's, so
   the planner's posterior sharpens about as fast as the filter's would; each
   predicted scan counts for the scans the sensor takes in ``scan_every``). The
   posterior over hypotheses is the prior weights times these likelihoods;
   the score is the entropy of the posterior over regions (``region`` m
   squares x ``region_headings`` heading sectors holding the hypotheses now:
   telling apart hypotheses of one mode, a bin apart, is not localizing),
   averaged over ``h`` with the prior weights.
   Teammates: when the truth ``h`` passes within ``detect_fraction`` of the
   detector range of a confident teammate's shared estimate (position std
   below ``confident_std``), a detection would follow, which rules out the
   hypotheses farther than ``detect_tolerance`` from ``h`` (their
   log-likelihood drops by ``detect_loglik``). The other way round, a
   confident robot subtracts from its score the entropy its lost teammates
   would expect to lose by meeting it: for each of their hypotheses within
   reach of its path, the hypothesis's weight times that teammate's entropy
   (times ``seek_weight``; off by default: on ``active_hallway`` it changed
   nothing measurable, and in a symmetric map confidently wrong robots then
   gather and agree on a wrong frame).
5. **Choice.** The primitive with the least ``expected entropy - team term +
   collision_cost * P(collision) - progress_weight * expected net
   displacement - straight_bonus [driving straight on]`` wins: information
   first, then safety, then forward progress (a robot whose belief has
   symmetric modes, where no primitive tells them apart within the horizon,
   keeps driving at full speed). The bonus for driving on means a robot turns
   only for a clear information gain: without it, small differences between
   the primitives' scores made robots dither back and forth in a corridor.

Between replans each robot tracks its primitive by its own odometry (the
heading it turned since the replan) and, like ``wander``, turns in place
toward the freer side when its own scan shows an obstacle ahead, then keeps
the new heading (optionally it also veers away from a wall close beside it,
``side_guard``). The planner reads the particle beliefs, the team's shared
estimates, the robot's own readings, the known map and the hardware, never
the true poses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl.beam_table import BeamLUT, RangeTable, beam_lut


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


def _sectors(angles: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
        front, lsec, rsec = _sectors(ang)
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



class MCLInfoGainPlanner:
    """Plans and tracks motion primitives for a team's MCL robots (see the module docstring).

    Args:
        n_hypotheses: most pose hypotheses per robot.
        replan_every: env steps between replans.
        primitives: the candidates (:func:`default_primitives` when ``None``).
        scorer: the :class:`PrimitiveScorer` (its defaults when ``None``).
        cell: m, position bin of the hypotheses.
        heading_bins: heading bins of the hypotheses.
        confident_std: m, a teammate whose shared position std is below this can
            inform a robot it detects.
        detect_fraction: fraction of the detector range within which a detection
            is expected.
        plan_sigma: m, the range noise of the planner's beam model (at least the
            filter's): hypotheses are bin means, a bin wide, so small range
            differences between them are no evidence.
        seek_weight: weight of the team term of a confident robot: the entropy its
            lost teammates would lose if it met them (0: no seeking).
        straight_bonus: nats subtracted from the score of driving straight on: a
            robot turns only for an information gain larger than this (no dithering).
        avoid: m, the tracker turns in place when its own scan shows a return this
            near ahead (the simulation of the primitives assumes ``AVOID``).
        side_guard: m, the tracker veers away from a return this near on a side
            (0: off). ``avoid=1.5, side_guard=0.6`` about halved the collisions in
            ``active_hallway`` but localized ~3 s later on average (within noise).
    """

    def __init__(self, n_hypotheses: int = 40, replan_every: int = 4,
                 primitives: tuple[Primitive, ...] | None = None,
                 scorer: PrimitiveScorer | None = None, cell: float = 1.0,
                 heading_bins: int = 12, confident_std: float = 1.0,
                 detect_fraction: float = 0.8, plan_sigma: float = 1.0,
                 seek_weight: float = 0.0, straight_bonus: float = 0.3,
                 avoid: float = AVOID, side_guard: float = 0.0) -> None:
        for key, value in (("n_hypotheses", n_hypotheses), ("replan_every", replan_every),
                           ("heading_bins", heading_bins)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be a positive integer, got {value!r}")
        for key, value in (("cell", cell), ("confident_std", confident_std),
                           ("plan_sigma", plan_sigma)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{key} must be > 0, got {value!r}")
        if not 0 <= detect_fraction <= 1:
            raise ValueError(f"detect_fraction must be in [0, 1], got {detect_fraction!r}")
        self.primitives = tuple(primitives) if primitives is not None else default_primitives()
        if not self.primitives or not all(isinstance(q, Primitive) for q in self.primitives):
            raise ValueError("primitives must be a non-empty sequence of Primitive")
        self.n_hypotheses, self.replan_every = n_hypotheses, replan_every
        self.scorer = scorer if scorer is not None else PrimitiveScorer()
        self.cell, self.heading_bins = float(cell), heading_bins
        self.confident_std, self.detect_fraction = float(confident_std), float(detect_fraction)
        self.plan_sigma = float(plan_sigma)
        if not (np.isfinite(seek_weight) and seek_weight >= 0):
            raise ValueError(f"seek_weight must be >= 0, got {seek_weight!r}")
        self.seek_weight = float(seek_weight)
        if not (np.isfinite(straight_bonus) and straight_bonus >= 0):
            raise ValueError(f"straight_bonus must be >= 0, got {straight_bonus!r}")
        self.straight_bonus = float(straight_bonus)
        for key, value in (("avoid", avoid), ("side_guard", side_guard)):
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be >= 0, got {value!r}")
        self.avoid, self.side_guard = float(avoid), float(side_guard)
        self._straight = np.array([q.turn == 0 and q.rate == 0 and q.speed > 0
                                   for q in self.primitives])
        self.env = None

    def reset(self, env, robots: dict[int, tuple[int, int]]) -> None:
        """Bind to ``env``; ``robots`` maps each MCL robot to ``(index of its backend in
        env.backends, its index in that backend)``."""
        self.env = env
        cfg = env.config
        self.robots = dict(robots)
        n = cfg.n_robots
        self.choice = np.zeros(n, dtype=int)  # index into primitives
        self.turned = np.zeros(n)  # rad turned since the last replan (own odometry)
        self.target = np.zeros(n)  # rad: heading to hold, relative to the one at the replan
        self.in_place = np.zeros(n, dtype=bool)  # still in the primitive's in-place turn
        self._count = 0
        self._angles = [np.asarray(a, dtype=float) for a in env.sensors.beam_angles]
        self._rmax = np.asarray(env.sensors.range_max, dtype=float)
        self._scans = [np.full(len(a), r) for a, r in zip(self._angles, self._rmax, strict=True)]
        self._dt_sub = cfg.dt / cfg.odometry_substeps
        self._scans_per_s = min(cfg.laser_rate, 1.0 / cfg.dt)
        specs = [cfg.robot_spec(i) for i in range(n)]
        self._has_range = np.array([s.has_range_sensor for s in specs])
        self._has_det = np.array([s.has_detector for s in specs])
        self._speed = np.array([s.max_speed for s in specs], dtype=float)
        self._turn_rate = np.array([s.max_turn_rate for s in specs], dtype=float)

    def model(self, i: int) -> ScanModel:
        """Robot ``i``'s :class:`ScanModel` (tables shared with its filter)."""
        b, local = self.robots[i]
        backend = self.env.backends[b]
        table, lut, angles, max_range = backend.beam_model(local)
        c = backend.particle_filter(local).config
        if self.plan_sigma > c.beam_sigma:
            lut = beam_lut(max_range, self.plan_sigma, c.beam_z_hit, c.beam_z_short,
                           c.beam_z_max, c.beam_z_rand, c.beam_lambda_short,
                           c.likelihood_exponent)
        return ScanModel(table, lut, np.asarray(angles, dtype=float),
                         self._scans_per_s if self._has_range[i] else 0.0,
                         float(self._speed[i]), float(self._turn_rate[i]))

    def _teammates(self, i: int, live: np.ndarray) -> np.ndarray:
        """``(m, 2)`` shared estimates of live, confident teammates that could inform ``i``."""
        env = self.env
        if not env.config.cooperative_updates:
            return np.zeros((0, 2))
        cov = env.estimated_covariances
        std = np.sqrt(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]))
        ok = live & (std < self.confident_std) & self._has_det  # the teammate detects ``i``
        ok[i] = False
        return env.estimated_poses[ok, :2]

    def hypotheses(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Robot ``i``'s pose hypotheses and weights (those inside walls left out)."""
        b, local = self.robots[i]
        particles = self.env.beliefs.samples[i]
        poses, weights = belief_hypotheses(particles.states, particles.weights,
                                           self.n_hypotheses, self.cell, self.heading_bins)
        table = self.env.backends[b].beam_model(local)[0]
        free = table.free((poses[:, 0] - table.origin[0]).astype(np.float32),
                          (poses[:, 1] - table.origin[1]).astype(np.float32))
        if free.any() and not free.all():  # hypotheses inside walls are impossible
            poses, weights = poses[free], weights[free] / weights[free].sum()
        return poses, weights

    def _confident(self) -> np.ndarray:
        cov = self.env.estimated_covariances
        return np.sqrt(0.5 * (cov[:, 0, 0] + cov[:, 1, 1])) < self.confident_std

    def plan_robot(self, i: int, live: np.ndarray,
                   hyps: dict[int, tuple[np.ndarray, np.ndarray]] | None = None
                   ) -> dict[str, np.ndarray]:
        """Score the primitives for robot ``i``; returns :meth:`PrimitiveScorer.scores`.

        ``hyps``: the robots' hypotheses when already drawn (:meth:`hypotheses`).
        """
        hyps = hyps if hyps is not None else {}
        poses, weights = hyps[i] if i in hyps else self.hypotheses(i)
        reach = self.detect_fraction * self.env.config.detector_range
        seek = None
        confident = self._confident()
        if self.seek_weight > 0 and confident[i] and self.env.config.cooperative_updates:
            points, nats = [], []
            for k in np.flatnonzero(live & ~confident):
                if k == i or k not in self.robots or not self._has_det[i]:  # ``i`` detects ``k``
                    continue
                pk, wk = hyps[k] if k in hyps else self.hypotheses(k)
                ent = float(-(wk * np.log(np.maximum(wk, 1e-300))).sum())
                points.append(pk[:, :2])
                nats.append(self.seek_weight * ent * wk)
            if points:
                seek = (np.concatenate(points), np.concatenate(nats))
        return self.scorer.scores(self.model(i), poses, weights, self.primitives,
                                  self._teammates(i, live), reach, seek)

    def _read(self) -> None:
        """Fold the last step's own odometry and scans into the trackers."""
        readings = self.env.last_readings
        if readings is None:
            return
        self.turned += readings.odometry[:, :, 1].sum(axis=0) * self._dt_sub
        for i in self.robots:
            if readings.range_mask[i]:
                row = np.asarray(readings.ranges[i][: len(self._angles[i])], dtype=float)
                self._scans[i] = np.where(np.isfinite(row), row, self._rmax[i])

    def act(self, agents: list[str]) -> dict[str, np.ndarray]:
        """Actions of the MCL robots among ``agents``: replan when due, then track."""
        env = self.env
        self._read()
        index = [env.agent_name_mapping[a] for a in agents]
        mine = [i for i in index if i in self.robots]
        if self._count % self.replan_every == 0:
            live = np.zeros(env.config.n_robots, dtype=bool)
            live[index] = True
            hyps = {i: self.hypotheses(i) for i in mine}
            for i in mine:
                score = self.plan_robot(i, live, hyps)["score"]
                score = score - self.straight_bonus * self._straight
                k = int(np.argmin(score))
                self.choice[i] = k
                self.turned[i] = 0.0
                self.target[i] = self.primitives[k].turn
                self.in_place[i] = abs(self.primitives[k].turn) > TURNED
        self._count += 1
        return {env.possible_agents[i]: self._track(i) for i in mine}

    def _track(self, i: int) -> np.ndarray:
        prim = self.primitives[self.choice[i]]
        if prim.speed <= 0:
            return np.zeros(2, dtype=np.float32)
        err = float(wrap_angle(self.target[i] - self.turned[i]))
        if self.in_place[i]:
            if abs(err) > TURNED:
                return np.array([0.0, np.clip(2.0 * err, -1.0, 1.0)], dtype=np.float32)
            self.in_place[i] = False
        self.target[i] += prim.rate * self.env.config.dt
        front, lsec, rsec = _sectors(self._angles[i])
        scan = self._scans[i]
        lmin = scan[lsec].min() if lsec.any() else np.inf
        rmin = scan[rsec].min() if rsec.any() else np.inf
        if front.any() and scan[front].min() < self.avoid:  # blocked: turn to the freer side
            self.target[i] = self.turned[i]
            return np.array([0.0, 0.8 if lmin >= rmin else -0.8], dtype=np.float32)
        if min(lmin, rmin) < self.side_guard:  # a wall close beside: veer away from it
            self.target[i] += SIDE_VEER if lmin >= rmin else -SIDE_VEER
            err = float(wrap_angle(self.target[i] - self.turned[i]))
        turn = np.clip(2.0 * err + prim.rate / self._turn_rate[i], -1.0, 1.0)
        return np.array([prim.speed * max(0.0, np.cos(err)) ** 2, turn], dtype=np.float32)
