"""Synthetic team data with known ground truth, for tests and benchmarks.

Two views of one dispersal experiment (robots start on a jittered grid filling a
room and drive outward, robot observations follow Howard et al.'s noise model):
:func:`random_team_graph` samples it at discrete times as a pose graph,
:func:`simulate_team_stream` as the odometry and observation stream an online
estimator (:class:`estimators.mle_online.TeamMLE`) consumes. Both draw their
observations with :func:`observe_pairs`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from estimators.pose_graph.graph import PoseGraph
from estimators.pose_graph.se2 import between, compose, se2_exp
from estimators.relative_metrics import relative_pose_matrix

Observation = tuple[int, int, np.ndarray, np.ndarray]
"""``(observer, target, (range, bearing, orientation), std)`` of one robot observation."""


@dataclass(frozen=True)
class PairSensing:
    """Howard et al.'s robot-observation model: each ordered pair closer than
    ``sensor_range`` is observed with probability ``p_observe``, with range noise
    ``max(range_frac * r, range_floor)`` and bearing and orientation noise ``angle_std``."""

    sensor_range: float
    p_observe: float
    range_frac: float = 0.05
    range_floor: float = 0.02
    angle_std: float = 0.03


def observe_pairs(
    poses: np.ndarray, rng: np.random.Generator, sensing: PairSensing
) -> list[Observation]:
    """Noisy observations of the team at true ``poses`` ``(N, 3)``, pairs in row-major order
    (one uniform draw per ordered pair in range, then the noise of those observed)."""
    rel = relative_pose_matrix(poses)
    seen = []
    for a, b in zip(*np.nonzero(rel[..., 0] <= sensing.sensor_range), strict=True):
        if a == b or rng.random() >= sensing.p_observe:
            continue
        rng_std = max(sensing.range_frac * rel[a, b, 0], sensing.range_floor)
        std = np.array([rng_std, sensing.angle_std, sensing.angle_std])
        meas = rel[a, b] + rng.normal(0.0, std)
        meas[0] = abs(meas[0])
        seen.append((int(a), int(b), meas, std))
    return seen


def start_cells(n_robots: int) -> tuple[np.ndarray, int]:
    """Cells ``(N, 2)`` (column, row) of the first ``n_robots`` cells of the smallest square
    grid that holds them, row by row, and that grid's side."""
    side = int(np.ceil(np.sqrt(n_robots)))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)
    return grid[:n_robots], side


@dataclass
class SyntheticTeam:
    """A random team pose graph and its ground truth (see :func:`random_team_graph`)."""

    graph: PoseGraph
    truth: np.ndarray
    node: np.ndarray
    """``node[robot, k]`` is the node id of ``robot`` at sampled time ``k``."""


def random_team_graph(
    n_robots: int,
    n_times: int,
    rng: np.random.Generator,
    *,
    room: float = 4.0,
    step: float = 1.5,
    motion_std: tuple[float, float] = (0.1, 0.05),
    p_still: float = 0.1,
    init_std: tuple[float, float] = (0.5, 0.2),
    sensing: PairSensing = PairSensing(sensor_range=8.0, p_observe=0.5),
) -> SyntheticTeam:
    """Synthetic dispersal experiment: robots start in a ``room`` and random-walk outward.

    Robots start on a jittered grid filling the room (so no two start on top of
    each other, where bearings are ill-conditioned).

    Motion factors link consecutive sampled times (tangent-space noise of std
    ``motion_std`` = (metres, radians)); each sampled time's robot observations follow
    ``sensing`` (:func:`observe_pairs`). A robot stands still with probability
    ``p_still`` per interval. The first pose of robot 0 is fixed at the truth; the
    initial estimate is dead reckoning from first poses perturbed by ``init_std``.
    """
    if n_robots < 1 or n_times < 1:
        raise ValueError(f"need n_robots, n_times >= 1, got {n_robots!r}, {n_times!r}")
    truth = _dispersal_walk(n_robots, n_times, rng, room, step, p_still)
    graph = PoseGraph()
    node = np.zeros((n_robots, n_times), dtype=int)
    sig_xy, sig_th = motion_std
    cov = np.diag([sig_xy**2, sig_xy**2, sig_th**2])
    for r in range(n_robots):
        est = truth[r, 0].copy()
        if r != 0:
            est += rng.normal(0.0, [init_std[0], init_std[0], init_std[1]])
        node[r, 0] = graph.add_node(est, robot=r, time=0.0, fixed=(r == 0))
        for k in range(1, n_times):
            rel = between(truth[r, k - 1], truth[r, k])
            eps = rng.normal(0.0, [sig_xy, sig_xy, sig_th])
            meas = compose(rel, se2_exp(-eps))  # so that Log(meas^-1 rel) = eps
            est = compose(est, meas)
            node[r, k] = graph.add_node(est, robot=r, time=float(k))
            graph.add_between(node[r, k - 1], node[r, k], meas, cov)
    for k in range(n_times):
        for a, b, meas, std in observe_pairs(truth[:, k], rng, sensing):
            graph.add_observation(node[a, k], node[b, k], meas, std=std)
    return SyntheticTeam(graph, truth.reshape(-1, 3), node)


def _dispersal_walk(
    n_robots: int, n_times: int, rng: np.random.Generator, room: float, step: float,
    p_still: float,
) -> np.ndarray:
    """True poses ``(N, T, 3)`` of :func:`random_team_graph`'s outward random walk."""
    truth = np.zeros((n_robots, n_times, 3))
    grid, side = start_cells(n_robots)
    cell = room / side
    truth[:, 0, :2] = (grid + 0.5 + rng.uniform(-0.25, 0.25, (n_robots, 2))) * cell
    truth[:, 0, 2] = rng.uniform(-np.pi, np.pi, n_robots)
    center = np.full(2, room / 2.0)
    for k in range(1, n_times):
        prev = truth[:, k - 1]
        outward = np.arctan2(prev[:, 1] - center[1], prev[:, 0] - center[0])
        turn = wrap_angle(0.5 * wrap_angle(outward - prev[:, 2]) + rng.normal(0, 0.4, n_robots))
        dist = rng.uniform(0.3, 1.0, n_robots) * step
        still = rng.random(n_robots) < p_still
        delta = np.stack([dist, np.zeros(n_robots), turn], axis=-1)
        delta[still] = 0.0
        truth[:, k] = compose(prev, delta)
    return truth


@dataclass
class TeamStream:
    """Synthetic sensor stream of a team (see :func:`simulate_team_stream`)."""

    dt: float
    truth: np.ndarray
    """True poses ``(n_steps + 1, N, 3)``; ``truth[k]`` is after ``k`` steps."""
    odometry: np.ndarray
    """Noisy ``(v, w)`` readings ``(n_steps, N, 2)``; reading ``k`` moves ``truth[k] -> [k+1]``."""
    observations: list[list[Observation]]
    """Per step ``k`` (taken at ``truth[k + 1]``): ``(observer, target, (r, b, o), std)``."""


def simulate_team_stream(
    n_robots: int,
    n_steps: int,
    rng: np.random.Generator,
    *,
    sensing: PairSensing = PairSensing(sensor_range=6.0, p_observe=0.05),
    dt: float = 0.1,
    room: float = 4.0,
    speed: float = 0.5,
    odometry_std: tuple[float, float] = (0.05, 0.05),
) -> TeamStream:
    """Robots start in a ``room`` and disperse; noisy odometry and robot observations.

    Speeds are uniform in ``[0, speed]`` (some robots nearly still), turn rates a
    random walk biased away from the room centre. Each step's robot observations
    follow ``sensing`` (:func:`observe_pairs`).
    """
    if n_robots < 1 or n_steps < 1 or not dt > 0:
        raise ValueError(f"need n_robots, n_steps >= 1 and dt > 0, got {n_robots, n_steps, dt}")
    n = n_robots
    grid, side = start_cells(n)
    truth = np.zeros((n_steps + 1, n, 3))
    truth[0, :, :2] = (grid + 0.5) * room / side + rng.uniform(-0.1, 0.1, (n, 2)) * room / side
    truth[0, :, 2] = rng.uniform(-np.pi, np.pi, n)
    v = rng.uniform(0.0, speed, n)
    v[rng.random(n) < 0.15] = 0.0
    centre = np.full(2, room / 2.0)
    odometry = np.zeros((n_steps, n, 2))
    observations = []
    sv, sw = odometry_std
    for k in range(n_steps):
        x = truth[k]
        outward = np.arctan2(x[:, 1] - centre[1], x[:, 0] - centre[0])
        w = 0.3 * np.sin(outward - x[:, 2]) + rng.normal(0.0, 0.3, n)
        w[v == 0] = 0.0
        c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
        truth[k + 1] = x + dt * np.stack([v * c, v * s, w], -1)
        odometry[k] = np.stack([v + rng.normal(0, sv, n), w + rng.normal(0, sw, n)], -1)
        observations.append(observe_pairs(truth[k + 1], rng, sensing))
    return TeamStream(dt, truth, odometry, observations)
