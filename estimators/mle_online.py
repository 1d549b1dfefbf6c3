"""Online maximum-likelihood team localization over a sliding-window pose graph.

One file: keyframing, gating, solving and marginalizing all work on TeamMLE's per-robot state.

:class:`TeamMLE` turns a stream of per-robot odometry ``(v, w, dt)`` and robot
observations (range, bearing, orientation of one robot seen by another, any
subset of the three) into the pose graph of :mod:`estimators.pose_graph`:

* **Nodes** are keyframes: each robot gets a new node once it has integrated
  ``motion_window`` seconds of odometry (10 s in Howard et al.), and also when
  an observation involving it arrives at least ``keyframe_interval`` seconds
  after its last node, so that a robot observation joins the two robots' poses
  *at the time it was taken* (the paper's graph). The odometry in between is
  integrated (Euler, the process model of Madhavan et al.'s Eq. 1) with its
  covariance; closing a window adds a motion factor.
* **Robot observations** closer in time to the keyframes than
  ``keyframe_interval`` are attached to the two robots' latest nodes through the
  odometry integrated since them (known pose offsets). With ``inflate_offsets``
  the offsets' covariance is propagated into the observation's covariance (their
  correlation with the next motion factor is ignored: slightly over-confident,
  which is why short offsets are preferred). At most one observation per ordered
  pair per ``observation_interval`` seconds is used, bounding the factor count.
  A measured range below ``min_range`` makes the bearing meaningless, so the
  bearing component is dropped for that observation.
* **Gauge**: the first node of the ``anchor`` robot is fixed at its initial pose;
  every other robot's first node gets a Gaussian prior (``initial_std``; by
  default very weak, so that a robot never seen by a teammate still has a
  well-posed, if huge, covariance).
* **Sliding window**: :meth:`TeamMLE.step` re-optimizes (warm-started from the
  previous solution, a few Levenberg-Marquardt iterations) and then marginalizes
  each robot's nodes beyond the last ``window`` ones into a dense prior (Schur
  complement), so the cost per step is bounded however long the episode.
  ``window=None`` keeps every node (full batch each step); ``keep_history=True``
  also records the whole graph for an offline re-solve (:meth:`TeamMLE.solve_batch`).

Data must be fed in time order: an observation relates the two robots' poses as
they are after all odometry added so far. Estimates live in an arbitrary global
frame fixed by the anchor; relative poses (:meth:`TeamMLE.relative_poses`) are
what the data determine.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.stats import chi2

from estimators.geometry import relative_pose, wrap_angle
from estimators.odometry_integration import (
    OdometryIntegrator,
    integrate_odometry,
    pose_jacobians,
)
from estimators.pose_graph import (
    COMPONENTS,
    DEFAULT_MIN_RANGE,
    PoseGraph,
    SolveResult,
    TeamStream,
    check_observation,
    compose,
    marginal_covariances,
    marginalize,
    optimize,
    simulate_team_stream,
    sqrt_information,
)
from estimators.relative_metrics import relative_pose_matrix

__all__ = [
    "UNKNOWN_POSE_STD",
    "OdometryIntegrator",
    "TeamMLE",
    "TeamStream",
    "feed_stream",
    "integrate_odometry",
    "simulate_team_stream",
]

UNKNOWN_POSE_STD = (1e3, 1e3, np.pi)
"""Default prior std (m, m, rad) on the first pose of robots other than the anchor."""


class TeamMLE:
    """Online maximum-likelihood localization of a robot team (sliding-window pose graph).

    Parameters
    ----------
    n_robots:
        Team size; robots are indexed ``0 .. n_robots - 1``.
    initial_poses:
        ``(N, 3)`` initial pose guesses (default: all at the origin).
    initial_std:
        Std devs ``(3,)`` or ``(N, 3)`` of the prior on each robot's first pose
        (default :data:`UNKNOWN_POSE_STD`). A row of zeros fixes that robot's first pose.
    anchor:
        Robot whose first pose is fixed (gauge); ``None`` to rely on priors only.
    odometry_std:
        Default std devs of forward speed (m/s) and turn rate (rad/s) readings.
    motion_window:
        Longest odometry span (s) integrated into one motion factor: a robot gets a
        new keyframe at least this often (10 s in Howard et al.).
    window:
        Keyframes kept per robot before older ones are marginalized; ``None`` for
        full batch (nothing marginalized).
    keep_history:
        Also record every node and factor for :meth:`solve_batch`.
    max_iterations:
        Levenberg-Marquardt iterations per :meth:`step` (warm start).
    observation_interval:
        Minimum odometry time (s) of the observer between two accepted observations
        of the same ordered pair; more frequent ones are ignored.
    min_range:
        Measured ranges below this (m) have their bearing dropped (undefined); the
        observation derivatives floor the estimated range at it too.
    keyframe_interval:
        An accepted observation starts fresh keyframes for both robots when they have
        integrated at least this much odometry (s) since their last one, so the
        observation joins nodes at its own time (exact model); shorter offsets are
        handled by attaching to the latest nodes. ``None``: keyframes only every
        ``motion_window``.
    tolerance:
        Relative cost decrease at which a step's optimization stops.
    solve_interval:
        Minimum team time (s, the largest robot odometry clock) between two
        optimizations in :meth:`step` unless a keyframe was added; in between, new
        observations wait and poses follow odometry. ``0``: solve whenever data arrived.
    motion_floor_std:
        Std devs (m, rad) added to every motion factor so a robot that did not move
        (or moved straight) still has a positive-definite motion covariance.
    inflate_offsets:
        Propagate the odometry covariance since the last keyframes into the
        covariance of robot observations attached to those keyframes.
    gate_prob:
        If set, reject observations whose innovation (against the current poses and
        marginal covariances; cross-covariance ignored) exceeds this chi-square
        quantile, a guard against false detections. Rejections are counted in
        ``n_gated``. ``None``: accept all (the least-squares MLE has no outlier model).
    """

    def __init__(
        self,
        n_robots: int,
        *,
        initial_poses: np.ndarray | None = None,
        initial_std: np.ndarray | None = None,
        anchor: int | None = 0,
        odometry_std: tuple[float, float] = (0.05, 0.05),
        motion_window: float = 10.0,
        window: int | None = 10,
        keep_history: bool = False,
        max_iterations: int = 10,
        observation_interval: float = 1.0,
        min_range: float = 1e-2,
        keyframe_interval: float | None = 1.0,
        tolerance: float = 1e-6,
        solve_interval: float = 0.0,
        motion_floor_std: tuple[float, float] = (1e-3, 1e-3),
        inflate_offsets: bool = True,
        gate_prob: float | None = None,
    ) -> None:
        _check_options(n_robots, anchor, motion_window, window, max_iterations,
                       observation_interval, min_range, keyframe_interval, tolerance,
                       solve_interval, gate_prob)
        self.n_robots = n = int(n_robots)
        self.solve_interval = float(solve_interval)
        self.keyframe_interval = None if keyframe_interval is None else float(keyframe_interval)
        self.gate_prob = None if gate_prob is None else float(gate_prob)
        self._gate_threshold = (
            {} if gate_prob is None else {k: float(chi2.ppf(gate_prob, k)) for k in (1, 2, 3)}
        )
        self._n_solves = 0
        self.n_gated = 0
        self._gate_cache: tuple | None = None
        self.tolerance = float(tolerance)
        self.odometry_std = self._check_std2(odometry_std, "odometry_std", allow_zero=True)
        floor = self._check_std2(motion_floor_std, "motion_floor_std", allow_zero=False)
        self._floor_cov = np.diag([floor[0] ** 2, floor[0] ** 2, floor[1] ** 2])
        self.motion_window = float(motion_window)
        self.window = None if window is None else int(window)
        self.max_iterations = int(max_iterations)
        self.observation_interval = float(observation_interval)
        self.min_range = float(min_range)
        self.inflate_offsets = bool(inflate_offsets)
        poses, std = _initial_belief(n, initial_poses, initial_std)
        self._start_graphs(poses, std, anchor, keep_history)
        self._dirty = True
        self._new_keyframe = True
        self._solved_at = -np.inf
        self._node_cov: np.ndarray | None = None
        self.last_result: SolveResult | None = None

    def _start_graphs(
        self, poses: np.ndarray, std: np.ndarray, anchor: int | None, keep_history: bool
    ) -> None:
        """The window graph (and the history graph) with every robot's first node: the
        anchor's (and those of robots with all-zero ``std``) fixed, the others under a
        Gaussian prior of std ``std[r]`` at ``poses[r]``; the per-robot bookkeeping."""
        n = self.n_robots
        # Observation derivatives floor the estimated range at min_range too: two
        # estimates micrometres apart would otherwise give a bearing information of
        # ~1e14 and an information matrix too ill-conditioned for its marginals.
        floor = max(self.min_range, DEFAULT_MIN_RANGE)
        self.graph = PoseGraph(min_range=floor)
        self.history: PoseGraph | None = PoseGraph(min_range=floor) if keep_history else None
        self._last = np.zeros(n, dtype=int)
        self._nodes: list[deque[int]] = [deque() for _ in range(n)]
        self._odom = [OdometryIntegrator.zero() for _ in range(n)]
        self._clock = np.zeros(n)
        self._last_seen: dict[tuple[int, int], float] = {}
        for r in range(n):
            fixed = (anchor is not None and r == int(anchor)) or bool(np.all(std[r] == 0))
            if not fixed and np.any(std[r] == 0):
                raise ValueError(f"initial_std row {r} mixes zero and non-zero: {std[r]!r}")
            node = self._add_node(poses[r], r, fixed)
            if not fixed:
                for g in self._graphs():
                    g.add_pose_prior(node, poses[r], std[r])

    # ------------------------------------------------------------- helpers
    @staticmethod
    def _check_std2(value, name: str, allow_zero: bool) -> tuple[float, float]:
        arr = np.asarray(value, dtype=float).reshape(-1)
        bad = arr.shape != (2,) or not np.all(np.isfinite(arr))
        bad = bad or np.any(arr < 0) or (not allow_zero and np.any(arr == 0))
        if bad:
            raise ValueError(f"{name} must be two {'non-negative' if allow_zero else 'positive'} "
                             f"numbers, got {value!r}")
        return float(arr[0]), float(arr[1])

    def _graphs(self) -> list[PoseGraph]:
        return [self.graph] if self.history is None else [self.graph, self.history]

    def _add_node(self, pose: np.ndarray, robot: int, fixed: bool = False) -> int:
        node = -1
        for g in self._graphs():
            node_g = g.add_node(pose, robot=robot, time=self._clock[robot], fixed=fixed)
            assert node < 0 or node_g == node, "history and window graphs out of step"
            node = node_g
        self._last[robot] = node
        self._nodes[robot].append(node)
        return node

    def _check_robot(self, robot: int, name: str) -> int:
        if not (isinstance(robot, int | np.integer) and 0 <= robot < self.n_robots):
            raise ValueError(f"{name} must be a robot index in [0, {self.n_robots}), got {robot!r}")
        return int(robot)

    # ---------------------------------------------------------------- input
    def add_odometry(
        self, robot: int, v: float, w: float, dt: float, std: tuple[float, float] | None = None
    ) -> None:
        """Integrate one odometry reading of ``robot``: speed ``v``, turn rate ``w`` over ``dt``.

        ``std`` overrides the default ``odometry_std`` for this reading. A keyframe
        (node and motion factor) is created once ``motion_window`` seconds are integrated.
        """
        robot = self._check_robot(robot, "robot")
        vals = np.array([v, w, dt], dtype=float)
        if not np.all(np.isfinite(vals)) or dt < 0:
            raise ValueError(f"odometry (v, w, dt) must be finite with dt >= 0, got {(v, w, dt)!r}")
        sv, sw = self.odometry_std if std is None else self._check_std2(std, "std", True)
        acc = self._odom[robot]
        acc.add(float(v), float(w), float(dt), sv, sw)
        self._clock[robot] += dt
        if acc.duration >= self.motion_window - 1e-9:
            self._close_window(robot)

    def add_odometry_team(
        self,
        v: np.ndarray,
        w: np.ndarray,
        dt: float,
        std_v: np.ndarray | float | None = None,
        std_w: np.ndarray | float | None = None,
    ) -> None:
        """Integrate odometry of every robot at once (vectorized over robots).

        ``v``, ``w`` are ``(N,)`` (one reading per robot) or ``(S, N)`` (``S``
        readings per robot in time order, each over ``dt`` seconds); ``std_v``,
        ``std_w`` broadcast to the same shape (default ``odometry_std``). The
        result equals calling :meth:`add_odometry` for each reading in order (up
        to rounding): keyframes close at the same readings.
        """
        n = self.n_robots
        v = np.asarray(v, dtype=float)
        w = np.asarray(w, dtype=float)
        if v.ndim == 1:
            v, w = v[None], w[None]
        if v.shape != w.shape or v.ndim != 2 or v.shape[1] != n:
            raise ValueError(f"v and w must both be ({n},) or (S, {n}), got {v.shape}, {w.shape}")
        dt = float(dt)
        if not (np.isfinite(dt) and dt >= 0) or not (np.isfinite(v).all() and np.isfinite(w).all()):
            raise ValueError(f"odometry must be finite with dt >= 0, got dt={dt!r}")
        sv = np.broadcast_to(np.asarray(self.odometry_std[0] if std_v is None else std_v, float),
                             v.shape)
        sw = np.broadcast_to(np.asarray(self.odometry_std[1] if std_w is None else std_w, float),
                             v.shape)
        if not (np.isfinite(sv).all() and np.isfinite(sw).all()) or (sv < 0).any() or (
            sw < 0
        ).any():
            raise ValueError("std_v and std_w must be finite and >= 0")
        delta = np.stack([acc.delta for acc in self._odom])
        cov = np.stack([acc.cov for acc in self._odom])
        dur = np.array([acc.duration for acc in self._odom])
        eye = np.broadcast_to(np.eye(3), (n, 3, 3))
        for k in range(v.shape[0]):
            c, s = np.cos(delta[:, 2]), np.sin(delta[:, 2])
            f = eye.copy()
            f[:, 0, 2] = -dt * v[k] * s
            f[:, 1, 2] = dt * v[k] * c
            qv, qw = (dt * sv[k]) ** 2, (dt * sw[k]) ** 2
            gqg = np.zeros((n, 3, 3))
            gqg[:, 0, 0] = c * c * qv
            gqg[:, 0, 1] = gqg[:, 1, 0] = c * s * qv
            gqg[:, 1, 1] = s * s * qv
            gqg[:, 2, 2] = qw
            cov = f @ cov @ f.transpose(0, 2, 1) + gqg
            delta = delta + dt * np.stack([v[k] * c, v[k] * s, w[k]], axis=1)
            dur = dur + dt
            self._clock += dt
            closing = np.flatnonzero(dur >= self.motion_window - 1e-9)
            for r in closing:
                self._odom[r] = OdometryIntegrator(delta[r].copy(), cov[r].copy(), float(dur[r]))
                self._close_window(int(r))
                delta[r], cov[r], dur[r] = 0.0, 0.0, 0.0
        for r in range(n):
            self._odom[r] = OdometryIntegrator(delta[r].copy(), cov[r].copy(), float(dur[r]))

    def _close_window(self, robot: int) -> None:
        acc = self._odom[robot]
        prev = int(self._last[robot])
        node = self._add_node(compose(self.graph.poses[prev], acc.delta), robot)
        for g in self._graphs():
            g.add_between(prev, node, acc.delta, acc.cov + self._floor_cov)
        self._odom[robot] = OdometryIntegrator.zero()
        self._dirty = True
        self._new_keyframe = True

    def add_observation(
        self,
        observer: int,
        target: int,
        measurement: np.ndarray,
        std: np.ndarray | None = None,
        components: str = COMPONENTS,
        cov: np.ndarray | None = None,
    ) -> bool:
        """Add ``observer``'s measurement of ``target``: range, bearing, orientation (a subset).

        ``components`` names the measured subset in order (``"rbo"``, ``"rb"``, ...);
        ``measurement`` and either ``std`` (independent std devs) or ``cov`` (a full
        covariance) follow it. Returns whether the observation was used: it is skipped
        when the same ordered pair was seen less than ``observation_interval`` ago, or
        (with ``gate_prob``) when it is implausible given the current beliefs.
        """
        a = self._check_robot(observer, "observer")
        b = self._check_robot(target, "target")
        if a == b:
            raise ValueError(f"a robot cannot observe itself (observer = target = {a})")
        meas = check_observation(components, measurement)
        k = len(components)
        if (std is None) == (cov is None):
            raise ValueError("give exactly one of std and cov")
        if std is not None:
            sd = np.asarray(std, dtype=float).reshape(-1)
            if sd.shape != (k,) or not np.all(np.isfinite(sd)) or np.any(sd <= 0):
                raise ValueError(f"std must be {k} positive numbers, got {std!r}")
            r_meas = np.diag(sd**2)
        else:
            r_meas = np.asarray(cov, dtype=float)
            if r_meas.shape != (k, k) or not np.all(np.isfinite(r_meas)):
                raise ValueError(f"cov must be a finite {k}x{k} matrix, got {r_meas!r}")
        last = self._last_seen.get((a, b))
        if last is not None and self._clock[a] - last < self.observation_interval - 1e-9:
            return False  # rate-limited (checked before the costlier validation below)
        if cov is not None:
            sqrt_information(r_meas, "cov")  # raises ValueError unless symmetric positive
        if "r" in components and "b" in components and meas[components.index("r")] < self.min_range:
            keep = [i for i, ch in enumerate(components) if ch != "b"]
            components = "".join(components[i] for i in keep)
            meas, r_meas = meas[keep], r_meas[np.ix_(keep, keep)]
        if self.gate_prob is not None and not self._plausible(a, b, meas, r_meas, components):
            self.n_gated += 1
            return False
        self._last_seen[(a, b)] = self._clock[a]
        if self.keyframe_interval is not None:
            for robot in (a, b):
                acc = self._odom[robot]
                if acc.duration > 0 and acc.duration >= self.keyframe_interval - 1e-9:
                    self._close_window(robot)
        cov = r_meas
        off_a, off_b = self._odom[a], self._odom[b]
        if self.inflate_offsets:
            cov = cov + self._offset_covariance(a, b, components)
        for g in self._graphs():
            g.add_observation(
                int(self._last[a]), int(self._last[b]), meas, cov=cov, components=components,
                offset_a=off_a.delta, offset_b=off_b.delta,
            )
        self._dirty = True
        return True

    def observation_due(self, observer: int, target: int) -> bool:
        """Whether an observation of ``target`` by ``observer`` would pass the rate limit.

        A cheap pre-check for callers with many detections per step: :meth:`add_observation`
        ignores observations of the same ordered pair within ``observation_interval``.
        """
        last = self._last_seen.get((int(observer), int(target)))
        return last is None or self._clock[observer] - last >= self.observation_interval - 1e-9

    def _plausible(
        self, a: int, b: int, meas: np.ndarray, r_meas: np.ndarray, components: str
    ) -> bool:
        """Chi-square gate on the innovation of a measurement (cross-covariance ignored)."""
        # Beliefs of the robots' current poses only change when odometry arrives or the
        # graph is re-optimized (closing a keyframe does not move them): one evaluation
        # serves every observation of a step.
        key = (float(self._clock.max()), self._n_solves)
        if self._gate_cache is None or self._gate_cache[0] != key:
            self._gate_cache = (key, self.poses(), self.covariances())
        _, poses, covs = self._gate_cache
        xa, xb = poses[a], poses[b]
        idx = [COMPONENTS.index(ch) for ch in components]
        nu = meas - relative_pose(xa, xb)[idx]
        for i, ch in enumerate(components):
            if ch != "r":
                nu[i] = wrap_angle(nu[i])
        g_a, g_b = _observation_jacobians(xa, xb, self.min_range)
        s = g_a @ covs[a] @ g_a.T + g_b @ covs[b] @ g_b.T
        s = s[np.ix_(idx, idx)] + r_meas
        d2 = float(nu @ np.linalg.solve(s, nu))
        return d2 <= self._gate_threshold[len(idx)]

    def _offset_covariance(self, a: int, b: int, components: str) -> np.ndarray:
        """Covariance the odometry since the two keyframes adds to a measurement (first order)."""
        oa, ob = self._odom[a], self._odom[b]
        ka, kb = self.graph.poses[self._last[a]], self.graph.poses[self._last[b]]
        g_a, g_b = _observation_jacobians(compose(ka, oa.delta), compose(kb, ob.delta),
                                          self.min_range)
        ja = g_a @ pose_jacobians(ka, oa.delta)[1]
        jb = g_b @ pose_jacobians(kb, ob.delta)[1]
        full = ja @ oa.cov @ ja.T + jb @ ob.cov @ jb.T
        idx = [COMPONENTS.index(ch) for ch in components]
        return full[np.ix_(idx, idx)]

    # ---------------------------------------------------------------- solve
    def step(self) -> SolveResult | None:
        """Re-optimize the window (if anything was added) and marginalize old keyframes.

        Returns the solver's result, or ``None`` when nothing new was added (or
        ``solve_interval`` has not elapsed and no keyframe was created).
        """
        now = float(self._clock.max())
        if not self._dirty or (
            not self._new_keyframe and now - self._solved_at < self.solve_interval - 1e-9
        ):
            return None
        self.last_result = optimize(
            self.graph, max_iterations=self.max_iterations, rel_tol=self.tolerance
        )
        self._dirty = self._new_keyframe = False
        self._solved_at = now
        self._n_solves += 1
        # Keyframe marginals now, reusing the solver's factorization; marginalizing
        # at this estimate below leaves them unchanged (Schur complement).
        try:
            self._node_cov = marginal_covariances(self.graph, self._last, self.last_result.factor)
        except ValueError:  # ill-posed window: covariances() will report it if asked
            self._node_cov = None
        if self.window is not None:
            drop = []
            for nodes in self._nodes:
                while len(nodes) > self.window:
                    drop.append(nodes.popleft())
            if drop:
                marginalize(self.graph, np.asarray(drop))
        return self.last_result

    def solve_batch(self, max_iterations: int = 100) -> np.ndarray:
        """Re-solve the whole recorded history offline; returns the latest poses ``(N, 3)``.

        Starts from the current estimates (marginalized nodes at their last values).
        Needs ``keep_history=True``; the online window is not changed.
        """
        if self.history is None:
            raise ValueError("solve_batch needs TeamMLE(keep_history=True)")
        self.history.poses[:] = self.graph.poses
        optimize(self.history, max_iterations=max_iterations)
        return self._current(self.history.poses)

    # --------------------------------------------------------------- output
    def _current(self, node_poses: np.ndarray) -> np.ndarray:
        deltas = np.stack([acc.delta for acc in self._odom])
        return compose(node_poses[self._last], deltas)

    def poses(self) -> np.ndarray:
        """Latest pose estimate of every robot, ``(N, 3)``: last keyframe (+) odometry since."""
        return self._current(self.graph.poses)

    def covariances(self) -> np.ndarray:
        """3x3 marginal covariance of every robot's latest pose, ``(N, 3, 3)``.

        Keyframe marginals come from the window's information matrix (recomputed
        after each optimization); the odometry since the keyframe adds its own
        covariance (first-order propagation).
        """
        if self._node_cov is None or len(self._node_cov) != self.n_robots or self._dirty:
            self._node_cov = marginal_covariances(self.graph, self._last)
        out = np.empty((self.n_robots, 3, 3))
        for r in range(self.n_robots):
            acc = self._odom[r]
            jx, ju = pose_jacobians(self.graph.poses[self._last[r]], acc.delta)
            out[r] = jx @ self._node_cov[r] @ jx.T + ju @ acc.cov @ ju.T
        return 0.5 * (out + out.transpose(0, 2, 1))

    def belief(self, robot: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, covariance)`` of one robot's latest pose, or of all robots if ``None``."""
        means, covs = self.poses(), self.covariances()
        if robot is None:
            return means, covs
        robot = self._check_robot(robot, "robot")
        return means[robot], covs[robot]

    def relative_poses(self) -> np.ndarray:
        """Estimated range, bearing, orientation of robot ``b`` seen from ``a``: ``(N, N, 3)``."""
        return relative_pose_matrix(self.poses())

    @property
    def n_active_nodes(self) -> int:
        """Nodes currently in the optimization window."""
        return int(np.count_nonzero(self.graph.active))


def feed_stream(
    estimator: TeamMLE, stream: TeamStream, steps: range | None = None, components: str = "rbo"
):
    """Feed ``stream`` into ``estimator`` step by step, yielding the step index after each.

    Each step adds every robot's odometry and the step's observations (restricted to
    ``components``), then calls :meth:`TeamMLE.step`.
    """
    idx = [COMPONENTS.index(ch) for ch in components]
    for k in range(len(stream.odometry)) if steps is None else steps:
        for r in range(estimator.n_robots):
            v, w = stream.odometry[k, r]
            estimator.add_odometry(r, v, w, stream.dt)
        for a, b, meas, std in stream.observations[k]:
            estimator.add_observation(a, b, meas[idx], std[idx], components)
        estimator.step()
        yield k


def _check_options(
    n_robots: int, anchor: int | None, motion_window: float, window: int | None,
    max_iterations: int, observation_interval: float, min_range: float,
    keyframe_interval: float | None, tolerance: float, solve_interval: float,
    gate_prob: float | None,
) -> None:
    """ValueError naming the first of :class:`TeamMLE`'s scalar options out of range."""
    if int(n_robots) < 1:
        raise ValueError(f"n_robots must be >= 1, got {n_robots!r}")
    n = int(n_robots)
    if anchor is not None and not 0 <= int(anchor) < n:
        raise ValueError(f"anchor must be a robot index in [0, {n}), got {anchor!r}")
    if not motion_window > 0:
        raise ValueError(f"motion_window must be > 0, got {motion_window!r}")
    if window is not None and int(window) < 1:
        raise ValueError(f"window must be >= 1 or None, got {window!r}")
    if int(max_iterations) < 1:
        raise ValueError(f"max_iterations must be >= 1, got {max_iterations!r}")
    if not observation_interval >= 0:
        raise ValueError(f"observation_interval must be >= 0, got {observation_interval!r}")
    if not min_range >= 0:
        raise ValueError(f"min_range must be >= 0, got {min_range!r}")
    if keyframe_interval is not None and not keyframe_interval >= 0:
        raise ValueError(f"keyframe_interval must be >= 0 or None, got {keyframe_interval!r}")
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance!r}")
    if not solve_interval >= 0:
        raise ValueError(f"solve_interval must be >= 0, got {solve_interval!r}")
    if gate_prob is not None and not 0.0 < gate_prob < 1.0:
        raise ValueError(f"gate_prob must be in (0, 1) or None, got {gate_prob!r}")


def _initial_belief(
    n: int, initial_poses: np.ndarray | None, initial_std: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """:class:`TeamMLE`'s first-pose guesses ``(n, 3)`` (default the origin) and prior std
    devs ``(n, 3)`` (default :data:`UNKNOWN_POSE_STD`), checked."""
    poses = np.zeros((n, 3)) if initial_poses is None else np.asarray(initial_poses, float)
    if poses.shape != (n, 3) or not np.all(np.isfinite(poses)):
        raise ValueError(f"initial_poses must be finite with shape ({n}, 3), got {poses!r}")
    std = np.asarray(UNKNOWN_POSE_STD if initial_std is None else initial_std, dtype=float)
    std = np.broadcast_to(std, (n, 3)) if std.shape in ((3,), (n, 3)) else None
    if std is None or not np.all(np.isfinite(std)) or np.any(std < 0):
        raise ValueError(f"initial_std must be (3,) or ({n}, 3) of std devs >= 0, got "
                         f"{initial_std!r}")
    return poses, std


def _observation_jacobians(
    xa: np.ndarray, xb: np.ndarray, min_range: float
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians (3x3 each) of the range, bearing and orientation of pose ``xb`` seen from
    ``xa`` w.r.t. ``xa`` and ``xb``, the range floored at ``min_range``."""
    dx, dy = xb[0] - xa[0], xb[1] - xa[1]
    r = max(float(np.hypot(dx, dy)), min_range, 1e-9)
    g_b = np.array([[dx / r, dy / r, 0.0], [-dy / r**2, dx / r**2, 0.0], [0.0, 0.0, 1.0]])
    g_a = -g_b
    g_a[1, 2] = -1.0
    return g_a, g_b
