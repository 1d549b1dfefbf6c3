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
   own tables: :meth:`coop_loc_env.backends.mcl.MCLBackend.beam_model`).
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

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl.beam_table import beam_lut
from policies.scripted.infogain_scoring import (
    AVOID,
    SIDE_VEER,
    TURNED,
    Primitive,
    PrimitiveScorer,
    ScanModel,
    belief_hypotheses,
    default_primitives,
    scan_sectors,
)


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
        front, lsec, rsec = scan_sectors(self._angles[i])
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
