"""Terrain-traversal state machine (Madhavan, Fregene, Parker, Fig. 7), one per robot.

States and transitions::

    Scan -------------> LockOn --------> AcquireImage --------> ElevGradient
    (turn in place one   (turn until the   (drive slowly along an   (drive toward the
     full circle, note    chosen object is  arc that keeps the       object, recording
     each object of       centred in the    object in view until     elevation; steer by
     interest and how     camera)           the depth-from-motion    the camera bearing)
     clearly it is seen)                    range is good enough)          |
      ^                                                                    v
      +------------------ ObjectAvoid <---------- object closer than ``stop_range``
                          (turn away, drive clear; a reached object is marked in the
                           global frame, on the team map, and never chosen again)

Fail-safe modes, checked before every state's own logic:

* **Boundary** (tip-over avoidance) uses the robot's *inclinometer*: when a new
  reading gives a slope ``atan(hypot(tan pitch, tan roll))`` above
  ``boundary_slope_deg`` (well below the tip-over limit), the robot reverses
  if the uphill side is ahead, turns to face downhill and drives clear. It
  also remembers the spot (estimated position pushed ``hazard_offset`` m
  uphill) as a hazard and drops objects whose straight path passes near a
  known hazard. Above ``slow_slope_deg`` it drives at ``slow_speed`` so that
  one 1 Hz reading cannot miss the band between the two thresholds.
* **ObjectAvoid** uses the *range sensor*: any return closer than
  ``avoid_range`` in the front sector while driving forward interrupts the
  state; the robot turns toward the freer side until the front is clear, drives
  ``clear_distance`` m and resumes what it was doing.

Objects a teammate has already marked on the team map (within
``same_object_radius``) are skipped. When no object is left to visit, Scan
picks an exploration waypoint in the freest laser direction that keeps away
from hazards and the world edge, and drives there in ElevGradient (a segment
``P1 -> P2`` without an object).

The machine sees only a :class:`~policies.scripted.view.RobotView`: its belief, its
latched pitch/roll and range bins, and its camera records. Its current state
is :attr:`TraversalFSM.state` (a :class:`State`), and :attr:`TraversalFSM.history`
counts steps per state, for logging.
"""

from __future__ import annotations

import enum
from collections import Counter
from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from policies.scripted.view import RobotView, ViewBuilder


class State(str, enum.Enum):
    """The states of the traversal machine."""

    SCAN = "Scan"
    LOCK_ON = "LockOn"
    ACQUIRE_IMAGE = "AcquireImage"
    ELEV_GRADIENT = "ElevGradient"
    OBJECT_AVOID = "ObjectAvoid"
    BOUNDARY = "Boundary"


@dataclass(frozen=True)
class FSMParams:
    """Tuning of :class:`TraversalFSM` (speeds are normalized action values).

    Distances in metres, angles in degrees, durations in env steps.
    """

    cruise_speed: float = 0.6
    slow_speed: float = 0.3
    turn_rate: float = 1.0
    steer_gain: float = 1.5
    avoid_range: float = 1.1
    clear_range: float = 1.8
    front_half_angle_deg: float = 40.0
    side_guard: float = 0.6
    side_half_angle_deg: float = 75.0
    clear_distance: float = 1.0
    stop_range: float = 1.6
    acquire_bearing_deg: float = 9.0
    acquire_std: float = 0.35
    acquire_rel_std: float = 0.05
    acquire_timeout: int = 60
    lock_tolerance_deg: float = 3.0
    lock_timeout: int = 80
    lost_timeout: int = 15
    drive_timeout: int = 500
    boundary_slope_deg: float = 17.0
    slow_slope_deg: float = 9.0
    reverse_distance: float = 0.6
    backoff_distance: float = 1.2
    hazard_offset: float = 1.5
    hazard_radius: float = 2.0
    explore_distance: float = 6.0
    edge_margin: float = 2.0
    same_object_radius: float = 1.5

    def validate(self) -> None:
        """Raise ``ValueError`` naming a bad parameter."""
        for key in ("cruise_speed", "slow_speed", "turn_rate"):
            value = getattr(self, key)
            if not 0 < value <= 1:
                raise ValueError(f"{key} must be in (0, 1], got {value!r}")
        if not self.slow_slope_deg < self.boundary_slope_deg < 90:
            raise ValueError(
                f"need slow_slope_deg < boundary_slope_deg < 90, got "
                f"{self.slow_slope_deg!r}, {self.boundary_slope_deg!r}"
            )
        if not 0 < self.avoid_range < self.clear_range:
            raise ValueError(
                f"need 0 < avoid_range < clear_range, got {self.avoid_range!r}, "
                f"{self.clear_range!r}"
            )


@dataclass
class _Object:
    """What the robot remembers about one object of interest."""

    xy: np.ndarray
    range_std: float
    clarity: float = 0.0


class TraversalFSM:
    """One robot's terrain-traversal state machine.

    Args:
        params: tuning (:class:`FSMParams`).
        rng: generator for tie-breaking choices (exploration side).
    """

    def __init__(self, params: FSMParams | None = None, rng: np.random.Generator | None = None):
        self.params = params or FSMParams()
        self.params.validate()
        self.rng = rng or np.random.default_rng(0)
        self.reset()

    def reset(self) -> None:
        """Forget everything (start of an episode)."""
        self.state = State.SCAN
        self.history: Counter[State] = Counter()
        self.transitions: list[tuple[int, State, State]] = []
        self.objects: dict[int, _Object] = {}
        self.visited: set[int] = set()
        self.unreachable: set[int] = set()
        self.hazards: list[np.ndarray] = []
        self.marked: list[tuple[float, float]] = []
        self.elevation_log: list[tuple[float, float, float]] = []
        self.target: int | None = None  # object id, or None for a waypoint
        self.waypoint: np.ndarray | None = None
        self._t = 0
        self._enter_t = 0
        self._scan_turned = 0.0
        self._scan_clarity: dict[int, float] = {}
        self._last_heading: float | None = None
        self._resume: State | None = None
        self._avoid_phase = "turn"
        self._avoid_dir = 1.0
        self._odo = 0.0
        self._last_xy: np.ndarray | None = None
        self._reached = False
        self._boundary_phase = "reverse"
        self._downhill = 0.0
        self._lost = 0
        self.pending_marks: list[tuple[float, float]] = []

    # ------------------------------------------------------------------ helpers
    def _go(self, state: State) -> None:
        if state != self.state:
            self.transitions.append((self._t, self.state, state))
        self.state = state
        self._enter_t = self._t
        self._odo = 0.0
        self._lost = 0
        if state == State.SCAN:
            self._scan_turned = 0.0
            self._scan_clarity = {}

    def _time_in_state(self) -> int:
        return self._t - self._enter_t

    def _note_objects(self, view: RobotView) -> dict[int, tuple[float, float]]:
        """Update remembered objects from the camera; returns ``id -> (bearing, range)``."""
        x, y, th = view.est_pose
        seen = {}
        for rec in view.camera:
            if rec.kind != "ooi":
                continue
            a = th + rec.bearing
            xy = np.array([x + rec.range * np.cos(a), y + rec.range * np.sin(a)])
            obj = self.objects.get(rec.id)
            if obj is None or rec.range_std <= obj.range_std + 1e-9 or self.target != rec.id:
                self.objects[rec.id] = _Object(xy, rec.range_std, obj.clarity if obj else 0.0)
            seen[rec.id] = (rec.bearing, rec.range)
        return seen

    def _path_hits_hazard(self, start: np.ndarray, goal: np.ndarray) -> bool:
        if not self.hazards:
            return False
        h = np.asarray(self.hazards)
        d = goal - start
        t = np.clip(((h - start) @ d) / max(float(d @ d), 1e-9), 0.0, 1.0)
        closest = np.hypot(*(h - (start + t[:, None] * d)).T)
        from_start = np.hypot(*(h - start).T)
        # A path that leads away from a nearby hazard is fine; one that closes in is not.
        return bool(((closest < self.params.hazard_radius) & (closest < from_start - 0.2)).any())

    def _marked_by_team(self, view: RobotView, xy: np.ndarray) -> bool:
        """Whether a teammate already marked an object near ``xy`` on the team map."""
        if len(view.team_objects) == 0:
            return False
        d = np.hypot(*(view.team_objects - xy).T)
        return bool((d < self.params.same_object_radius).any())

    def _goal_xy(self) -> np.ndarray | None:
        if self.target is not None and self.target in self.objects:
            return self.objects[self.target].xy
        return self.waypoint

    def _steer_to(self, view: RobotView, goal: np.ndarray) -> tuple[float, float]:
        """Bearing error (rad) and distance (m) from the belief to ``goal``."""
        d = goal - view.est_pose[:2]
        return float(wrap_angle(np.arctan2(d[1], d[0]) - view.est_pose[2])), float(np.hypot(*d))

    def _speed(self, view: RobotView) -> float:
        p = self.params
        return p.slow_speed if view.slope > np.deg2rad(p.slow_slope_deg) else p.cruise_speed

    def _front_blocked(self, view: RobotView) -> bool:
        """An obstacle ahead within ``avoid_range``, or beside within ``side_guard``."""
        p = self.params
        half = np.deg2rad(p.front_half_angle_deg)
        side = np.deg2rad(p.side_half_angle_deg)
        return view.min_range(-half, half) < p.avoid_range or (
            view.min_range(-side, side) < p.side_guard
        )

    def _drop_target(self) -> None:
        if self.target is not None:
            self.unreachable.add(self.target)
        self.target = None
        self.waypoint = None

    # ------------------------------------------------------------------ step
    def act(self, view: RobotView) -> np.ndarray:
        """The normalized action ``(v, w)`` for this step; updates :attr:`state`."""
        p = self.params
        xy = view.est_pose[:2]
        if self._last_xy is not None:
            self._odo += float(np.hypot(*(xy - self._last_xy)))
        self._last_xy = xy.copy()
        if view.incl_new:
            self.elevation_log.append((float(xy[0]), float(xy[1]), view.pitch))
        seen = self._note_objects(view)
        # Fail-safe 1: tip-over terrain (inclinometer).
        if (
            view.incl_new
            and view.slope > np.deg2rad(p.boundary_slope_deg)
            and self.state != State.BOUNDARY
        ):
            self._enter_boundary(view)
        # Fail-safe 2: an obstacle in front while driving forward (range sensor).
        elif self.state in (State.ACQUIRE_IMAGE, State.ELEV_GRADIENT) and self._front_blocked(
            view
        ):
            target_close = (
                self.target is not None
                and self.target in seen
                and seen[self.target][1] < p.stop_range + 0.5
            )
            self._enter_avoid(view, reached=target_close)
        handler = {
            State.SCAN: self._scan,
            State.LOCK_ON: self._lock_on,
            State.ACQUIRE_IMAGE: self._acquire,
            State.ELEV_GRADIENT: self._elev_gradient,
            State.OBJECT_AVOID: self._object_avoid,
            State.BOUNDARY: self._boundary,
        }[self.state]
        action = handler(view, seen)
        self.history[self.state] += 1
        self._t += 1
        return np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)

    # ------------------------------------------------------------------ states
    def _scan(self, view: RobotView, seen: dict) -> tuple[float, float]:
        p = self.params
        heading = float(view.est_pose[2])
        if self._time_in_state() > 0 and self._last_heading is not None:
            self._scan_turned += abs(float(wrap_angle(heading - self._last_heading)))
        self._last_heading = heading
        for oid, (_b, r) in seen.items():
            # Clarity: frames in view during the scan, weighted by closeness.
            self._scan_clarity[oid] = self._scan_clarity.get(oid, 0.0) + 1.0 / (1.0 + r)
        if self._scan_turned < 2 * np.pi:
            return 0.0, p.turn_rate
        for oid, c in self._scan_clarity.items():
            self.objects[oid].clarity = c
        candidates = [
            oid
            for oid, c in sorted(self._scan_clarity.items(), key=lambda kv: -kv[1])
            if oid not in self.visited
            and oid not in self.unreachable
            and not self._marked_by_team(view, self.objects[oid].xy)
            and not self._path_hits_hazard(view.est_pose[:2], self.objects[oid].xy)
        ]
        if candidates:
            self.target = candidates[0]
            self.waypoint = None
            self._go(State.LOCK_ON)
            return 0.0, 0.0
        self.target = None
        self.waypoint = self._explore_waypoint(view)
        self._go(State.ELEV_GRADIENT)
        return 0.0, 0.0

    def _explore_waypoint(self, view: RobotView) -> np.ndarray:
        """A point ``explore_distance`` ahead in the freest direction, away from hazards/edges."""
        p = self.params
        w, h = view.world_size
        x, y, th = view.est_pose
        angles = np.linspace(-np.pi, np.pi, 24, endpoint=False)
        score = self.rng.random(24) * 0.5
        best, best_score = None, -np.inf
        for a, s in zip(angles, score, strict=True):
            dist = p.explore_distance
            goal = np.array([x + dist * np.cos(th + a), y + dist * np.sin(th + a)])
            inside = p.edge_margin <= goal[0] <= w - p.edge_margin and (
                p.edge_margin <= goal[1] <= h - p.edge_margin
            )
            if not inside or self._path_hits_hazard(view.est_pose[:2], goal):
                continue
            free = view.min_range(a - 0.2, a + 0.2) if abs(a) <= np.pi / 2 else view.max_range / 2
            sc = s + min(free, dist) / dist
            if sc > best_score:
                best, best_score = goal, sc
        if best is None:  # boxed in: head for the middle of the world
            best = np.array([w / 2, h / 2])
        return best

    def _lock_on(self, view: RobotView, seen: dict) -> tuple[float, float]:
        p = self.params
        if self.target in seen:
            err = seen[self.target][0]
        else:
            err, _ = self._steer_to(view, self.objects[self.target].xy)
        if abs(err) < np.deg2rad(p.lock_tolerance_deg) and self.target in seen:
            self._go(State.ACQUIRE_IMAGE)
            return 0.0, 0.0
        if self._time_in_state() > p.lock_timeout:
            self._drop_target()
            self._go(State.SCAN)
            return 0.0, 0.0
        return 0.0, float(np.clip(p.steer_gain * err, -p.turn_rate, p.turn_rate))

    def _acquire(self, view: RobotView, seen: dict) -> tuple[float, float]:
        p = self.params
        if self.target not in seen:
            self._lost += 1 if view.camera_frame else 0
            if self._lost > p.lost_timeout:
                self._go(State.LOCK_ON)
            err, _ = self._steer_to(view, self.objects[self.target].xy)
            return 0.0, float(np.clip(p.steer_gain * err, -p.turn_rate, p.turn_rate))
        self._lost = 0
        bearing, rng = seen[self.target]
        rec = next(c for c in view.camera if c.kind == "ooi" and c.id == self.target)
        good = rec.range_std < max(p.acquire_std, p.acquire_rel_std * rng)
        if good or self._time_in_state() > p.acquire_timeout or rng < p.stop_range + 1.0:
            if self._path_hits_hazard(view.est_pose[:2], self.objects[self.target].xy):
                self._drop_target()
                self._go(State.SCAN)
                return 0.0, 0.0
            self._go(State.ELEV_GRADIENT)
            return 0.0, 0.0
        # Keep the object off-centre so the camera's path has a sideways component.
        err = bearing - np.deg2rad(p.acquire_bearing_deg)
        return p.slow_speed, float(np.clip(p.steer_gain * err, -p.turn_rate, p.turn_rate))

    def _elev_gradient(self, view: RobotView, seen: dict) -> tuple[float, float]:
        p = self.params
        goal = self._goal_xy()
        if goal is None:
            self._go(State.SCAN)
            return 0.0, 0.0
        err, dist = self._steer_to(view, goal)
        if self.target is not None:
            if self.target in seen:
                err, dist = seen[self.target]
            if dist < p.stop_range:
                self._enter_avoid(view, reached=True)
                return self._object_avoid(view, seen)
        elif dist < 0.5:  # exploration waypoint reached
            self.waypoint = None
            self._go(State.SCAN)
            return 0.0, 0.0
        if self._time_in_state() > p.drive_timeout or self._path_hits_hazard(
            view.est_pose[:2], goal
        ):
            self._drop_target()
            self._go(State.SCAN)
            return 0.0, 0.0
        w = float(np.clip(p.steer_gain * err, -1.0, 1.0))
        v = self._speed(view) * max(0.0, float(np.cos(err))) ** 2
        return v, w

    def _enter_avoid(self, view: RobotView, reached: bool) -> None:
        half = np.deg2rad(self.params.front_half_angle_deg)
        left = view.min_range(half, np.pi / 2 + 0.01)
        right = view.min_range(-np.pi / 2 - 0.01, -half)
        self._avoid_dir = 1.0 if left >= right else -1.0
        self._avoid_phase = "turn"
        self._reached = reached
        if reached and self.target is not None:
            xy = self.objects[self.target].xy
            self.visited.add(self.target)
            self.marked.append((float(xy[0]), float(xy[1])))
            self.pending_marks.append((float(xy[0]), float(xy[1])))
            self.target = None
        self._resume = State.SCAN if reached else self.state
        if self._resume == State.ACQUIRE_IMAGE:
            self._resume = State.LOCK_ON
        self._go(State.OBJECT_AVOID)

    def _object_avoid(self, view: RobotView, seen: dict) -> tuple[float, float]:
        p = self.params
        half = np.deg2rad(p.front_half_angle_deg)
        front = view.min_range(-half, half)
        if self._avoid_phase == "turn":
            turned_enough = self._time_in_state() * view.dt * p.turn_rate > (
                np.pi / 2 if self._reached else 0.0
            )
            if front > p.clear_range and turned_enough:
                self._avoid_phase = "clear"
                self._odo = 0.0
            elif self._time_in_state() > 2 * np.pi / (p.turn_rate * view.dt):
                self._avoid_phase = "clear"  # turned a full circle: take the freest way
                self._odo = 0.0
            else:
                return 0.0, self._avoid_dir * p.turn_rate
        if self._front_blocked(view):
            self._avoid_phase = "turn"
            return 0.0, self._avoid_dir * p.turn_rate
        if self._odo >= p.clear_distance:
            resume = self._resume or State.SCAN
            if resume in (State.ELEV_GRADIENT, State.LOCK_ON) and self._goal_xy() is None:
                resume = State.SCAN
            self._go(resume)
            return 0.0, 0.0
        return self._speed(view), 0.0

    def _enter_boundary(self, view: RobotView) -> None:
        x, y, th = view.est_pose
        uphill_rel = float(np.arctan2(np.tan(view.roll), np.tan(view.pitch)))
        uphill = th + uphill_rel
        offset = self.params.hazard_offset * np.array([np.cos(uphill), np.sin(uphill)])
        self.hazards.append(np.array([x, y]) + offset)
        self._downhill = float(wrap_angle(uphill + np.pi))
        self._boundary_phase = "reverse" if np.cos(uphill_rel) > 0.3 else "turn"
        goal = self._goal_xy()
        if goal is not None and self._path_hits_hazard(view.est_pose[:2], goal):
            self._drop_target()
        self._go(State.BOUNDARY)

    def _boundary(self, view: RobotView, seen: dict) -> tuple[float, float]:
        p = self.params
        if self._boundary_phase == "reverse":
            if self._odo < p.reverse_distance:
                return -p.slow_speed, 0.0
            self._boundary_phase = "turn"
        if self._boundary_phase == "turn":
            err = float(wrap_angle(self._downhill - view.est_pose[2]))
            if abs(err) > np.deg2rad(10.0):
                return 0.0, float(np.clip(p.steer_gain * err, -p.turn_rate, p.turn_rate))
            self._boundary_phase = "drive"
            self._odo = 0.0
        if self._odo >= p.backoff_distance or self._front_blocked(view):
            self._go(State.SCAN)
            return 0.0, 0.0
        err = float(wrap_angle(self._downhill - view.est_pose[2]))
        return p.slow_speed, float(np.clip(p.steer_gain * err, -1.0, 1.0))


class FSMPolicy:
    """A :class:`TraversalFSM` per robot, acting on each robot's own view.

    Objects a robot reaches are reported to the team map
    (:meth:`~coop_loc_env.env.CoopLocParallelEnv.mark_object`).

    Args:
        params: tuning shared by every robot's machine.
    """

    name = "fsm"

    def __init__(self, params: FSMParams | None = None) -> None:
        self.params = params or FSMParams()
        self.params.validate()
        self.machines: dict[str, TraversalFSM] = {}
        self.env = None
        self._views: ViewBuilder | None = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset) and start a fresh machine per robot."""
        self.env = env
        self._views = ViewBuilder(env)
        base = np.random.SeedSequence(seed)
        self.machines = {
            agent: TraversalFSM(self.params, np.random.default_rng(s))
            for agent, s in zip(env.possible_agents, base.spawn(len(env.possible_agents)),
                                strict=True)
        }

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent."""
        actions = {}
        for agent in self.env.agents:
            fsm = self.machines[agent]
            actions[agent] = fsm.act(self._views.view(agent, obs[agent]))
            while fsm.pending_marks:
                x, y = fsm.pending_marks.pop()
                self.env.mark_object(agent, x, y)
        return actions

    def states(self) -> dict[str, str]:
        """Current state name of every robot's machine (for logging)."""
        return {agent: m.state.value for agent, m in self.machines.items()}
