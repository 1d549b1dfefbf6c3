"""Random team pose graphs with known ground truth, for tests and benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from estimators.pose_graph.graph import PoseGraph
from estimators.pose_graph.se2 import between, compose, se2_exp
from estimators.relative_metrics import relative_pose_matrix


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
    sensor_range: float = 8.0,
    p_observe: float = 0.5,
    motion_std: tuple[float, float] = (0.1, 0.05),
    range_frac: float = 0.05,
    range_floor: float = 0.02,
    angle_std: float = 0.03,
    p_still: float = 0.1,
    init_std: tuple[float, float] = (0.5, 0.2),
) -> SyntheticTeam:
    """Synthetic dispersal experiment: robots start in a ``room`` and random-walk outward.

    Robots start on a jittered grid filling the room (so no two start on top of
    each other, where bearings are ill-conditioned).

    Motion factors link consecutive sampled times (tangent-space noise of std
    ``motion_std`` = (metres, radians)); each ordered pair closer than
    ``sensor_range`` is observed with probability ``p_observe`` with range noise
    ``max(range_frac * r, range_floor)`` and bearing/orientation noise ``angle_std``
    (Howard et al.'s noise model). A robot stands still with probability
    ``p_still`` per interval. The first pose of robot 0 is fixed at the truth; the
    initial estimate is dead reckoning from first poses perturbed by ``init_std``.
    """
    if n_robots < 1 or n_times < 1:
        raise ValueError(f"need n_robots, n_times >= 1, got {n_robots!r}, {n_times!r}")
    truth = np.zeros((n_robots, n_times, 3))
    side = int(np.ceil(np.sqrt(n_robots)))
    cell = room / side
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n_robots]
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
        rel = relative_pose_matrix(truth[:, k])
        for a in range(n_robots):
            for b in range(n_robots):
                if a == b or rel[a, b, 0] > sensor_range or rng.random() >= p_observe:
                    continue
                std = np.array([max(range_frac * rel[a, b, 0], range_floor), angle_std, angle_std])
                meas = rel[a, b] + rng.normal(0.0, std)
                meas[0] = abs(meas[0])
                graph.add_observation(node[a, k], node[b, k], meas, std=std)
    return SyntheticTeam(graph, truth.reshape(-1, 3), node)

