"""``hypothesis``: hypothesis elimination with far targets (active Markov localization).

Fox, Burgard and Thrun's active localization picks *relative* target points
anywhere in the map, weighing what the robot expects to learn there against
the occupancy-based cost of the path; Dudek, Romanik and Whitesides drive to
where the hypotheses predict different readings. Here, for every robot that
runs MCL:

1. **Modes.** The belief's top modes (:func:`estimators.mcl.modes.particle_modes`,
   the same extraction as the dict observation's ``belief_modes``); those above
   ``min_weight`` are the hypotheses. While they hold less than ``min_cover``
   of the mass (early in global localization), the robot explores as ``corridor``.
2. **A lead mode.** Targets are relative to the robot: they are expressed in the
   frame of one mode (the heaviest when planning starts), tracked from step to
   step; under mode ``m`` the same relative target lies at ``T_m q`` with
   ``T_m = pose_m * lead^-1``.
3. **Where the modes disagree.** For every drivable cell ``q`` of the planning grid
   (:class:`~policies.scripted.planning.PlanGrid`), each mode's predicted scan at
   ``T_m q`` (the filter's own range table; a place inside a wall reads 0) is
   compared with every other mode's: ``sim = exp(-rms^2 / (2 scan_sigma^2))``;
   the expected mass eliminated there is ``1 - sum_mm' w_m w_m' sim_mm'``.
4. **Far target, geodesic cost.** The target maximizes that gain minus
   ``cost_weight`` times the path cost from the lead's cell (Dijkstra on the
   planning grid, which keeps to the middle of corridors) plus ``turn_cost`` per
   radian the robot must turn first. The robot drives the path by the lead
   mode's pose, toward a look-ahead point ``lookahead`` m along it, steering by
   the free space of its own scan around that direction (:func:`toward`).
5. **Replanning.** When the lead mode dies (no mode within ``TRACK_M`` and
   ``TRACK_RAD`` of it), when the number of hypotheses changed and the target's
   gain has halved, when the target was reached and ``dwell`` steps passed (that
   target is then left out while the lead lives), and every ``replan_every``
   steps (a new target must then beat the current one by ``switch_margin``).

Team: lost robots test different hypotheses (a robot's candidate targets within
``ASSIGN_M`` of a target a teammate chose earlier in the same step lose
``assign_penalty``, when both lead poses are within detector range of each other,
so that the two frames agree). A robot whose heaviest mode weighs at least
``localized_weight`` is confident; it is *trusted* when it became confident with
no detection (as observer or target) in the ``sighting_hold`` steps before: a
detection between two lost robots can leave both confident in the same wrong
copy of a symmetric map. With ``meet="trusted"`` (the default) trusted robots
drive to meet the lost teammates: to the mode of theirs with the best weight
per metre of path, so that a detection passes their belief on (modes visited
without a meeting are left out for ``forget`` steps); other confident robots
explore as ``corridor``. Options, off by default: ``meet_gain`` adds to a lost
robot's gain the mass a meeting with a trusted teammate would eliminate (under
mode ``m`` the target lies within half the detector range of it); ``verify``
sends an untrusted confident robot to the nearest place that looks like nowhere
else (:func:`distinctive_cells`) and trusts it if its scan matches there.

It reads the particle beliefs, the known map, the robot's own scan and the
team's communicated beliefs; never the true poses. Robots that do not run MCL
drive as ``corridor``.
"""

from __future__ import annotations

import math

import numpy as np

from coop_loc_env.belief_map import TeamBeliefs
from estimators.geometry import wrap_angle
from estimators.mcl.modes import particle_modes
from policies.scripted.corridor import SIDE, SIDE_GAIN, SLOW, TURN_PENALTY, CorridorPolicy, follow
from policies.scripted.planning import PlanGrid

TRACK_M = 1.5  # m: the lead mode is the mode nearest its last pose within this ...
TRACK_RAD = 0.7  # ... and within this of its heading (rad)
ASSIGN_M = 3.0  # m: two robots' targets this close test the same hypothesis
VISITED_M = 3.0  # m: candidates this close to a target visited without an answer are left out
REACHED_M = 1.0  # m: a target is reached within this
CLOSE = 0.5  # m: a return nearer than this ahead makes the robot turn in place
MODE_RADIUS = 2.0  # m: mode extraction radius (as the dict observation's)
MODE_HEADING_TOL = math.pi / 4
MEET_MODES = ("trusted", "all", "off")
SELECT_MODES = ("utility", "nearest")
SWITCH_M = 2.0  # m: with select="nearest", a new target must be this much nearer


class _Robot:
    """One robot's planning state."""

    def __init__(self) -> None:
        self.clear()
        self.visited_mates: list[tuple[int, np.ndarray]] = []  # (step, xy) met without luck
        self.trusted: bool | None = None  # confident on its own readings (None: not confident)
        self.verify_failed = False  # its scan at a distinctive place did not match
        self.last_sighting = -(10**9)  # step of its last detection (as observer or target)
        self.resolved = False  # tested a place since its main mode last jumped (copies)
        self.top: np.ndarray | None = None  # the filter's heaviest mode at the last step

    def clear(self) -> None:
        self.lead: np.ndarray | None = None  # lead mode pose (x, y, heading)
        self.target: np.ndarray | None = None  # target (lead frame, x y)
        self.tree: np.ndarray | None = None  # predecessors toward the target cell
        self.since = 0  # steps since the last plan
        self.n_modes = 0
        self.planned_gain = 0.0  # the target's gain when it was chosen
        self.dwell = 0
        self.visited: list[np.ndarray] = []


def _compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose ``a * b`` (b expressed in a's frame)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2]])


def _inverse(a: np.ndarray) -> np.ndarray:
    c, s = math.cos(a[2]), math.sin(a[2])
    return np.array([-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2]])


class HypothesisPolicy(CorridorPolicy):
    """Hypothesis elimination with far targets (module doc).

    Args:
        n_modes: modes extracted per robot.
        min_weight: a mode is a hypothesis from this weight.
        min_cover: the hypotheses must hold this much mass, else the robot explores.
        localized_weight: a robot whose heaviest mode weighs this is localized.
        scan_sigma: m, the RMS scan difference at which two modes count as told apart.
        cost_weight: gain given up per metre of path cost.
        turn_cost: metres of path cost per radian turned toward the path first.
        replan_every: steps between plans while nothing changes.
        dwell: steps a reached target waits for an answer.
        lookahead: m along the path of the point steered to.
        assign_penalty: gain lost by a target a teammate tests already.
        forget: steps a teammate's mode visited without a meeting is left out.
        switch_margin: gain a new target must add over the current one at a periodic replan.
        meet: which confident robots drive to meet the lost ones: ``"trusted"``, ``"all"``
            or ``"off"``.
        sighting_hold: steps after a detection during which a robot that becomes
            confident is not trusted.
        verify: send untrusted confident robots to a distinctive place to check.
        distinct: m, the :func:`distinctive_cells` value of a distinctive place.
        verify_rms: m, the largest RMS scan mismatch there that confirms the belief.
        meet_gain: weight of the gain of meeting a trusted teammate (0: off).
        select: ``"utility"`` (gain less path cost, far targets) or ``"nearest"`` (the
            nearest place, by path and turn, whose gain reaches ``nearest_gain`` times
            the best gain: greedy hypothesis testing).
        nearest_gain: with ``select="nearest"``, the share of the best gain a place needs.
        copies: a mode that lies on a symmetric copy of the heaviest one (under a turn
            that maps the known map onto itself, :func:`estimators.mcl.map_symmetry.
            map_symmetries`) weighs as much as it: the filter keeps such copies, with
            little mass, exactly while the robot's own scans cannot reject them.
    """

    name = "hypothesis"

    def __init__(self, n_modes: int = 8, min_weight: float = 0.04, min_cover: float = 0.5,
                 localized_weight: float = 0.9, scan_sigma: float = 0.5,
                 cost_weight: float = 0.01, turn_cost: float = 1.0, replan_every: int = 20,
                 dwell: int = 8, lookahead: float = 1.5, assign_penalty: float = 0.2,
                 forget: int = 40, switch_margin: float = 0.05, meet: str = "trusted",
                 sighting_hold: int = 6, verify: bool = False, distinct: float = 1.0,
                 verify_rms: float = 0.8, meet_gain: float = 0.0, select: str = "utility",
                 nearest_gain: float = 0.5, copies: bool = False) -> None:
        super().__init__(1.0)
        for key, value in (("min_weight", min_weight), ("min_cover", min_cover),
                           ("localized_weight", localized_weight)):
            if not 0 < value <= 1:
                raise ValueError(f"{key} must be in (0, 1], got {value!r}")
        for key, value in (("scan_sigma", scan_sigma), ("lookahead", lookahead)):
            if not value > 0:
                raise ValueError(f"{key} must be > 0, got {value!r}")
        for key, value in (("cost_weight", cost_weight), ("turn_cost", turn_cost),
                           ("assign_penalty", assign_penalty)):
            if not value >= 0:
                raise ValueError(f"{key} must be >= 0, got {value!r}")
        for key, value in (("n_modes", n_modes), ("replan_every", replan_every),
                           ("dwell", dwell), ("forget", forget)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be a positive integer, got {value!r}")
        self.n_modes, self.min_weight, self.min_cover = n_modes, min_weight, min_cover
        self.localized_weight, self.scan_sigma = localized_weight, scan_sigma
        self.cost_weight, self.turn_cost = cost_weight, turn_cost
        self.replan_every, self.dwell, self.lookahead = replan_every, dwell, lookahead
        self.assign_penalty, self.forget = assign_penalty, forget
        self.switch_margin = float(switch_margin)
        if meet not in MEET_MODES:
            raise ValueError(f"meet must be one of {MEET_MODES}, got {meet!r}")
        self.meet, self.sighting_hold = meet, int(sighting_hold)
        self.verify, self.distinct = bool(verify), float(distinct)
        self.verify_rms = float(verify_rms)
        self.meet_gain = float(meet_gain)
        if select not in SELECT_MODES:
            raise ValueError(f"select must be one of {SELECT_MODES}, got {select!r}")
        if not 0 < nearest_gain <= 1:
            raise ValueError(f"nearest_gain must be in (0, 1], got {nearest_gain!r}")
        self.select, self.nearest_gain = select, float(nearest_gain)
        if not isinstance(copies, bool):
            raise ValueError(f"copies must be True or False, got {copies!r}")
        self.copies = copies

    # ------------------------------------------------------------------ setup
    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset): planning grids, scan models, fresh state."""
        super().reset(env, seed)
        cfg = env.config
        self.models: dict[int, tuple] = {}  # robot -> (range table, beam angles, max range)
        grids: dict[int, object] = {}
        for backend in env.backends:
            filters = getattr(backend, "filters", None)
            if not filters:
                continue
            for local, g in enumerate(np.asarray(backend.robots).tolist()):
                table, _, angles, max_range = backend.beam_model(local)
                self.models[g] = (table, np.asarray(angles, dtype=np.float32), max_range)
                grids[g] = filters[local].grid
        self.plans: dict[int, PlanGrid] = {}
        by_grid: dict[int, PlanGrid] = {}
        clearance = cfg.robot_radius + 0.25
        for g, grid in grids.items():
            key = id(grid)
            if key not in by_grid:
                by_grid[key] = plan_grid(grid, cfg.world_size, clearance)
            self.plans[g] = by_grid[key]
        self.state = {g: _Robot() for g in self.models}
        self.symmetries: dict[int, tuple] = {}
        if self.copies:
            from coop_loc_env.backends.mcl import SYMMETRY_OVERLAP
            from estimators.mcl.map_symmetry import map_symmetries

            self.symmetries = {g: map_symmetries(grids[g], SYMMETRY_OVERLAP) for g in grids}
        self.distinctive: dict[int, np.ndarray] = {}  # robot -> its map's distinctive cells
        for g in self.models:
            table, angles, max_range = self.models[g]
            self.distinctive[g] = _distinctive(self.plans[g], table, angles, max_range,
                                               self.distinct)
        self.t = 0
        self._trusted: dict[int, np.ndarray] = {}

    # ------------------------------------------------------------------ acting
    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent."""
        env = self.env
        index = env.agent_name_mapping
        live = [index[a] for a in env.agents]
        readings = env.last_readings
        if readings is not None and len(readings.detections):
            det = readings.detections
            for i in set(det.observer.tolist()) | set(det.target.tolist()):
                if i in self.state:
                    self.state[i].last_sighting = self.t
        modes = self._modes(live)
        self._trusted = {j: np.array([modes[j][0, 1], modes[j][0, 2]]) for j in live
                         if j in self.state and self.state[j].trusted and len(modes[j])
                         and modes[j][0, 0] >= self.localized_weight}
        targets: list[tuple[np.ndarray, np.ndarray]] = []  # (lead pose, target) chosen so far
        out = {}
        for a, i in zip(env.agents, live, strict=True):
            view = self._view(i)
            if i not in self.models:
                out[a] = follow(view, self.speed, self.gain)
                continue
            out[a] = self._robot(i, view, modes, live, targets)
        self.t += 1
        return out

    def _modes(self, live: list[int]) -> dict[int, np.ndarray]:
        """Each live MCL robot's modes ``(M, 6)`` (weight, x, y, cos, sin, spread) above
        ``min_weight``, heaviest first."""
        env = self.env
        beliefs = TeamBeliefs.from_env(env)
        w, h = env.config.world_size
        out: dict[int, np.ndarray] = {}
        for robots, flat, wt, ends, org in beliefs.blocks():
            rows = particle_modes(flat, wt, ends, org, self.n_modes, MODE_RADIUS,
                                  MODE_HEADING_TOL, (0.0, 0.0, w, h))
            for g, m in zip(robots.tolist(), rows, strict=True):
                if self.symmetries.get(g) and g in self.state:
                    m = self._copies(self.state[g], m, self.symmetries[g])
                out[g] = m[m[:, 0] >= self.min_weight]
        return out

    def _copies(self, st: _Robot, m: np.ndarray, symmetries) -> np.ndarray:
        """``m`` with the symmetric copies of the main mode raised (:func:`_raise_copies`)
        until the robot has tested a place (reached a target and waited ``dwell`` steps
        there: its scans have seen where the modes differ); a jump of the main mode
        starts over."""
        top = None if not len(m) or m[0, 0] <= 0 else np.array(
            [m[0, 1], m[0, 2], math.atan2(m[0, 4], m[0, 3])])
        if top is None or st.top is None or (
                math.hypot(*(top[:2] - st.top[:2])) > TRACK_M
                or abs(wrap_angle(top[2] - st.top[2])) > TRACK_RAD):
            st.resolved = False
        st.top = top
        return m if st.resolved else _raise_copies(m, symmetries)[0]

    def _robot(self, i: int, view, modes: dict[int, np.ndarray], live: list[int],
               targets: list) -> np.ndarray:
        st = self.state[i]
        m = modes[i]
        poses = np.column_stack([m[:, 1], m[:, 2], np.arctan2(m[:, 4], m[:, 3])])
        if len(m) and m[0, 0] >= self.localized_weight:
            st.clear()
            if st.trusted is None:  # just became confident: on its own readings?
                st.trusted = self.t - st.last_sighting > self.sighting_hold
            if not st.trusted and self.verify:
                return self._verify(i, view, poses[0])
            if self.meet == "all" or (self.meet == "trusted" and st.trusted):
                return self._meet(i, view, poses[0], modes, live)
            return follow(view, self.speed, self.gain)
        st.trusted = None
        st.verify_failed = False
        if m[:, 0].sum() < self.min_cover or len(m) < 1:
            st.clear()
            return follow(view, self.speed, self.gain)
        lead = self._track(st, poses)
        replan = lead is None or st.target is None
        if lead is None:
            st.clear()
            lead = poses[0]
        st.lead = lead
        if not replan and np.hypot(*(st.target - lead[:2])) < REACHED_M:
            st.dwell += 1
            if st.dwell >= self.dwell:
                st.visited.append(st.target.copy())
                st.resolved = True  # its scans have seen a place where the modes differ
                replan = True
        if not replan and len(poses) != st.n_modes:  # a hypothesis died or appeared
            gain = self._gain(i, lead, poses, m[:, 0] / m[:, 0].sum(), st.target[None])[0] \
                if len(poses) > 1 else 0.0
            replan = gain < 0.5 * st.planned_gain
            st.n_modes = len(poses)
        if replan or st.since >= self.replan_every:
            self._plan(i, st, poses, m[:, 0], targets, keep=not replan)
        st.since += 1
        if st.target is None:
            return follow(view, self.speed, self.gain)
        targets.append((lead.copy(), st.target.copy()))
        return self._drive(i, view, lead, st.tree, st.target)

    def _track(self, st: _Robot, poses: np.ndarray) -> np.ndarray | None:
        """The mode continuing the lead (``None`` when it died)."""
        if st.lead is None or not len(poses):
            return None
        d = np.hypot(poses[:, 0] - st.lead[0], poses[:, 1] - st.lead[1])
        dh = np.abs(wrap_angle(poses[:, 2] - st.lead[2]))
        ok = (d < TRACK_M) & (dh < TRACK_RAD)
        if not ok.any():
            return None
        return poses[int(np.argmin(np.where(ok, d, np.inf)))]

    # ------------------------------------------------------------------ planning
    def _plan(self, i: int, st: _Robot, poses: np.ndarray, weights: np.ndarray,
              targets: list, keep: bool = False) -> None:
        """Choose the lead-frame target (module doc, steps 3-4); with ``keep``, the current
        target stays unless another beats it by ``switch_margin``."""
        plan = self.plans[i]
        lead = st.lead
        st.since, st.n_modes = 0, len(poses)
        w = weights / weights.sum()
        cand = plan.centres[plan.free_index]  # (C, 2) lead-frame points
        gain = self._gain(i, lead, poses, w, cand) if len(poses) > 1 else np.zeros(len(cand))
        mates = [p for j, p in self._trusted.items() if j != i]
        if mates and self.meet_gain > 0:
            gain = gain + self.meet_gain * self._meet_gain(lead, poses, w, cand, np.array(mates))
        src = int(plan.cell_of(lead[:2]))
        dist, _ = plan.distances(src)
        cost = dist[plan.free_index]
        d = cand - lead[:2]
        turn = np.abs(wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - lead[2]))
        utility = gain - self.cost_weight * (cost + self.turn_cost * turn)
        for p in st.visited:
            utility[np.hypot(*(cand - p).T) < VISITED_M] = -np.inf
        reach = self.env.config.detector_range
        for other_lead, other_target in self._teammate_targets(i, targets):
            if np.hypot(*(other_lead[:2] - lead[:2])) < reach:
                utility[np.hypot(*(cand - other_target).T) < ASSIGN_M] -= self.assign_penalty
        utility[~np.isfinite(cost)] = -np.inf
        if self.select == "nearest":  # the nearest place that tells the modes apart well
            ok = np.isfinite(utility) & (utility > -np.inf)
            good = ok & (gain >= max(0.02, self.nearest_gain * float(gain[ok].max(initial=0))))
            if good.any():
                # the penalties (visited places, teammates' targets) stay: a penalized
                # place is skipped while an unpenalized good one remains
                penalty = gain - self.cost_weight * (cost + self.turn_cost * turn) - utility
                near = np.where(good, cost + self.turn_cost * turn + 100.0 * penalty, np.inf)
                utility = np.where(good, -near, -np.inf)
        best = int(np.argmax(utility))
        if keep and st.target is not None:
            now = int(np.argmin(np.hypot(*(cand - st.target).T)))
            margin = self.switch_margin if self.select == "utility" else SWITCH_M
            if utility[best] < utility[now] + margin:
                return
        st.dwell = 0
        if not np.isfinite(utility[best]) or gain[best] < 0.02:
            st.target, st.tree = None, None
            return
        st.target = cand[best].copy()
        st.planned_gain = float(gain[best])
        st.tree = plan.distances(int(plan.free_index[best]))[1]

    def _teammate_targets(self, i: int, targets: list) -> list:
        """``(lead pose, target)`` of the teammates whose places robot ``i``'s plan avoids:
        those chosen earlier in this step."""
        return targets

    def _meet_gain(self, lead: np.ndarray, poses: np.ndarray, w: np.ndarray, cand: np.ndarray,
                   mates: np.ndarray) -> np.ndarray:
        """Expected eliminated mass at each candidate from meeting a trusted teammate: under
        mode ``m`` the candidate lies at ``T_m q``; a teammate there detects the robot,
        which confirms ``m`` (eliminating ``1 - w_m``)."""
        reach = 0.5 * self.env.config.detector_range
        rel = _inverse(lead)
        out = np.zeros(len(cand))
        for pose, wm in zip(poses, w, strict=True):
            t = _compose(pose, rel)
            c, s = math.cos(t[2]), math.sin(t[2])
            x = t[0] + c * cand[:, 0] - s * cand[:, 1]
            y = t[1] + s * cand[:, 0] + c * cand[:, 1]
            d = np.hypot(x[:, None] - mates[None, :, 0], y[:, None] - mates[None, :, 1])
            out += wm * (1.0 - wm) * (d.min(axis=1) < reach)
        return out

    def _gain(self, i: int, lead: np.ndarray, poses: np.ndarray, w: np.ndarray,
              cand: np.ndarray) -> np.ndarray:
        """Expected eliminated mass at each candidate (module doc, step 3)."""
        table, angles, rmax = self.models[i]
        rel = _inverse(lead)
        scans = []
        ox, oy = table.origin
        for pose in poses:
            t = _compose(pose, rel)  # lead frame -> mode m's frame
            c, s = math.cos(t[2]), math.sin(t[2])
            x = t[0] + c * cand[:, 0] - s * cand[:, 1]
            y = t[1] + s * cand[:, 0] + c * cand[:, 1]
            head = np.full(len(cand), pose[2], dtype=np.float32)
            xs, ys = (x - ox).astype(np.float32), (y - oy).astype(np.float32)
            scan = table.expected(xs, ys, head, angles)
            scan = np.where(table.free(xs, ys)[:, None], np.minimum(scan, rmax), 0.0)
            scans.append(scan)
        s = np.stack(scans)  # (M, C, B)
        msd = ((s[:, None] - s[None, :]) ** 2).mean(axis=-1)  # (M, M, C)
        sim = np.exp(-0.5 * msd / self.scan_sigma**2)
        return 1.0 - np.einsum("m,n,mnc->c", w, w, sim)

    def _verify(self, i: int, view, pose: np.ndarray) -> np.ndarray:
        """A robot confident after a teammate's detection drives to the nearest place that
        looks like nowhere else (:func:`distinctive_cells`); confident there, it is trusted."""
        plan = self.plans[i]
        cells = self.distinctive[i]
        src = int(plan.cell_of(pose[:2]))
        st = self.state[i]
        if st.verify_failed or not len(cells):
            return follow(view, self.speed, self.gain)
        if src in set(cells.tolist()):  # there: does the own scan match the belief's?
            table, angles, max_range = self.models[i]
            ox, oy = table.origin
            f32 = np.float32
            expect = table.expected(np.array([pose[0] - ox], f32), np.array([pose[1] - oy], f32),
                                    np.array([pose[2]], f32), angles)[0]
            got = np.minimum(view.ranges, max_range)
            rms = float(np.sqrt(np.mean((np.minimum(expect, max_range) - got) ** 2)))
            st.trusted = rms <= self.verify_rms
            st.verify_failed = not st.trusted
            return follow(view, self.speed, self.gain)
        dist, _ = plan.distances(src)
        target = int(cells[np.argmin(dist[cells])])
        if not np.isfinite(dist[target]):
            return follow(view, self.speed, self.gain)
        tree = plan.distances(target)[1]
        return self._drive(i, view, pose, tree, plan.centres[target])

    # ------------------------------------------------------------------ team
    def _meet(self, i: int, view, pose: np.ndarray, modes: dict[int, np.ndarray],
              live: list[int]) -> np.ndarray:
        """A localized robot drives to the lost teammates' likeliest reachable modes."""
        st = self.state[i]
        st.visited_mates = [(t, p) for t, p in st.visited_mates if self.t - t < self.forget]
        plan = self.plans[i]
        src = int(plan.cell_of(pose[:2]))
        dist, _ = plan.distances(src)
        best, best_score = None, 0.0
        reach = self.env.config.detector_range
        for j in live:
            mj = modes.get(j)
            if j == i or mj is None or (len(mj) and mj[0, 0] >= self.localized_weight):
                continue
            for row in mj:
                xy = row[1:3]
                if any(np.hypot(*(p - xy)) < VISITED_M for _, p in st.visited_mates):
                    continue
                d = float(dist[int(plan.cell_of(xy))])
                if not np.isfinite(d):
                    continue
                if d < 0.5 * reach:  # here and no meeting: that mode is not where j is
                    st.visited_mates.append((self.t, xy.copy()))
                    continue
                score = row[0] / (d + reach)
                if score > best_score:
                    best, best_score = xy, score
        if best is None:
            return follow(view, self.speed, self.gain)
        cell = int(plan.cell_of(best))
        tree = plan.distances(cell)[1]
        return self._drive(i, view, pose, tree, plan.centres[cell])

    # ------------------------------------------------------------------ driving
    def _drive(self, i: int, view, pose: np.ndarray, tree: np.ndarray, target: np.ndarray
               ) -> np.ndarray:
        """Steer along the path toward ``target`` by ``pose``; reflex on the own scan."""
        plan = self.plans[i]
        cell = int(plan.cell_of(pose[:2]))
        point = target
        walked = 0.0
        prev = plan.centres[cell]
        for _ in range(int(self.lookahead / plan.cell) * 2 + 2):
            nxt = int(tree[cell])
            if nxt < 0:
                break
            step = plan.centres[nxt]
            walked += float(np.hypot(*(step - prev)))
            prev, cell, point = step, nxt, step
            if walked >= self.lookahead:
                break
        d = point - pose[:2]
        err = float(wrap_angle(math.atan2(d[1], d[0]) - pose[2]))
        return toward(view, err, self.speed)


def _raise_copies(m: np.ndarray, symmetries) -> tuple[np.ndarray, bool]:
    """Modes ``m`` (heaviest first) with each symmetric copy of the heaviest raised to its
    weight, renormalized over the raised mass, heaviest first; and whether any copy was
    there."""
    from estimators.mcl.map_symmetry import symmetric_copies

    m = m[m[:, 0] > 0].copy()
    if len(m) < 2:
        return m, False
    top = np.array([m[0, 1], m[0, 2], math.atan2(m[0, 4], m[0, 3])])
    heads = np.arctan2(m[:, 4], m[:, 3])
    raised = False
    for sym in symmetries:
        c = symmetric_copies(top, sym)
        d = np.hypot(m[:, 1] - c[0], m[:, 2] - c[1])
        ok = (d < TRACK_M) & (np.abs(wrap_angle(heads - c[2])) < TRACK_RAD)
        ok[0] = False
        if ok.any():
            k = int(np.argmin(np.where(ok, d, np.inf)))
            m[k, 0] = max(m[k, 0], m[0, 0])
            raised = True
    if not raised:
        return m, False
    total = m[:, 0].sum()
    m[:, 0] *= min(1.0, 1.0 / total) if total > 0 else 1.0
    return m[np.argsort(-m[:, 0], kind="stable")], True


def toward(view, err: float, speed: float = 1.0) -> np.ndarray:
    """An action ``[forward, turn]`` heading ``err`` rad off the robot's heading, by the
    free space of its own scan: the beam with the most range less ``TURN_PENALTY`` per
    radian off ``err`` is steered to (as ``corridor`` does around straight ahead), pushed
    off the nearer side wall; turn in place when ``err`` is behind or something is close."""
    if abs(err) > 2.0:
        return np.array([0.0, 1.0 if err > 0 else -1.0], dtype=np.float32)
    bearing = np.arctan2(np.sin(view.angles), np.cos(view.angles))
    off = np.abs(wrap_angle(bearing - err))
    score = np.where(off <= 1.0, np.minimum(view.ranges, view.max_range) - TURN_PENALTY * off,
                     -np.inf)
    heading = float(bearing[int(np.argmax(score))])
    left, right = view.min_range(*SIDE), view.min_range(-SIDE[1], -SIDE[0])
    if view.min_range(-0.6, 0.6) < CLOSE:  # back off while turning to the freer side
        back = -0.3 if view.min_range(math.pi - 0.6, math.pi) > CLOSE and \
            view.min_range(-math.pi, -math.pi + 0.6) > CLOSE else 0.0
        return np.array([back, 0.8 if left >= right else -0.8], dtype=np.float32)
    heading += SIDE_GAIN * float(np.clip(left - right, -1.0, 1.0))
    slow = min(1.0, view.min_range(-0.4, 0.4) / SLOW)
    forward = speed * max(0.0, math.cos(heading)) ** 2 * slow
    return np.array([forward, float(np.clip(3.0 * heading, -1.0, 1.0))], dtype=np.float32)


def distinctive_cells(plan: PlanGrid, table, angles: np.ndarray, max_range: float,
                      headings: int = 8, apart: float = 3.0) -> np.ndarray:
    """``(C,)`` per drivable cell of ``plan`` (``plan.free_index`` order): the RMS difference
    (m) between the scan predicted there (heading 0) and the most similar scan predicted
    anywhere else (``apart`` m away or more, any of ``headings`` headings): large where the
    map looks like nowhere else (a place that confirms a confident belief)."""
    pts = plan.centres[plan.free_index]
    ox, oy = table.origin
    xs = np.repeat((pts[:, 0] - ox).astype(np.float32), headings)
    ys = np.repeat((pts[:, 1] - oy).astype(np.float32), headings)
    hs = np.tile((np.arange(headings) * (2 * np.pi / headings)).astype(np.float32), len(pts))
    scans = np.minimum(table.expected(xs, ys, hs, angles), max_range).reshape(
        len(pts), headings, -1)
    ref = scans[:, 0]  # (C, B)
    other = scans.reshape(-1, scans.shape[-1])  # (C * headings, B)
    far = np.hypot(pts[:, None, 0] - pts[None, :, 0], pts[:, None, 1] - pts[None, :, 1]) >= apart
    best = np.full(len(pts), np.inf)
    for k in range(headings):  # one heading of the others at a time (memory)
        o = other[k::headings]
        msd = (ref ** 2).mean(1)[:, None] + (o ** 2).mean(1)[None, :] - 2 * ref @ o.T / ref.shape[1]
        best = np.minimum(best, np.where(far, msd, np.inf).min(axis=1))
    return np.sqrt(np.maximum(best, 0.0))


_PLAN_CACHE: dict[tuple, PlanGrid] = {}
_DISTINCT_CACHE: dict[tuple, np.ndarray] = {}


def _distinctive(plan: PlanGrid, table, angles, max_range: float, threshold: float
                 ) -> np.ndarray:
    """Cell indices of ``plan`` whose :func:`distinctive_cells` value reaches ``threshold``
    (cached per planning grid, table and threshold)."""
    key = (id(plan), id(table), float(threshold))
    hit = _DISTINCT_CACHE.get(key)
    if hit is None or _DISTINCT_CACHE.get((key, "plan")) is not plan:
        d = distinctive_cells(plan, table, angles, max_range)
        hit = plan.free_index[d >= threshold]
        if len(_DISTINCT_CACHE) > 32:
            _DISTINCT_CACHE.clear()
        _DISTINCT_CACHE[key] = hit
        _DISTINCT_CACHE[(key, "plan")] = plan
    return hit


def plan_grid(grid, world_size, clearance: float) -> PlanGrid:
    """A :class:`PlanGrid` of ``grid`` (cached per map, clearance and world size)."""
    key = (id(grid), tuple(world_size), float(clearance))
    plan = _PLAN_CACHE.get(key)
    if plan is None or plan.grid is not grid:
        plan = PlanGrid(grid, world_size, cell=0.5, clearance=clearance)
        if len(_PLAN_CACHE) > 16:
            _PLAN_CACHE.clear()
        _PLAN_CACHE[key] = plan
    return plan
