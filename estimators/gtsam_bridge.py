"""The same pose graph in GTSAM: an independent check of :func:`estimators.pose_graph.optimize`.

Needs the optional ``gtsam`` package (``pip install coop-loc-env[check]``);
imported only when a function here is called. :func:`to_gtsam` writes a
:class:`~estimators.pose_graph.PoseGraph` as a GTSAM factor graph with the same
cost ``U(X)``, factor by factor:

* motion factors: ``BetweenFactorPose2`` (the same SE(2) logarithm residual)
  with the factor's square-root information;
* robot observations (range, bearing, orientation, diagonal noise, no pose
  offsets): ``BearingRangeFactorPose2`` plus an orientation-only
  ``BetweenFactorPose2`` (zero precision on the translation);
* linear priors (start-pose priors, marginalization results): a
  ``CustomFactor`` with the prior's exact residual ``A (x_S - x0) + b`` (angles
  wrapped);
* fixed nodes: a ``PriorFactorPose2`` of standard deviation 1e-9 at their pose.

:func:`gtsam_solve` runs GTSAM's Levenberg-Marquardt on it and reports the
time, the iterations and the cost, in the units of
:meth:`~estimators.pose_graph.PoseGraph.cost` (``0.5 * sum`` of squared
whitened residuals).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from estimators.geometry import wrap_angle
from estimators.pose_graph import LinearPrior, PoseGraph, compose


@dataclass
class GtsamResult:
    """Outcome of :func:`gtsam_solve`."""

    poses: np.ndarray
    """Optimized poses ``(n_nodes, 3)`` (inactive nodes keep ``start``)."""
    cost: float
    iterations: int
    seconds: float
    cpu_seconds: float


def _prior_factor(gtsam, prior: LinearPrior):
    """A ``CustomFactor`` with residual ``A (x_S - x0) + b`` (heading differences wrapped)."""
    keys = [int(n) for n in prior.nodes]
    A, x0, b = prior.A, prior.x0, prior.b

    def error(this, values, jacobians):
        poses = np.array([[p.x(), p.y(), p.theta()] for p in
                          (values.atPose2(k) for k in this.keys())])
        d = poses - x0
        d[:, 2] = wrap_angle(d[:, 2])
        if jacobians is not None:
            for i, th in enumerate(poses[:, 2]):
                # GTSAM's Pose2 tangent is the body-frame (vx, vy, w): rotate to world x, y.
                c, s = np.cos(th), np.sin(th)
                local = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                jacobians[i] = A[:, 3 * i: 3 * i + 3] @ local
        return A @ d.ravel() + b

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(len(b)), keys, error)


def to_gtsam(graph: PoseGraph, start: np.ndarray):
    """``(NonlinearFactorGraph, Values)`` with the cost of ``graph``'s active part at ``start``.

    Raises ``ValueError`` for factors GTSAM's stock factors cannot express exactly
    (robot observations with pose offsets, correlated noise or a subset of the three
    components).
    """
    import gtsam

    start = np.asarray(start, dtype=float)
    if start.shape != (graph.n_nodes, 3):
        raise ValueError(f"start must be ({graph.n_nodes}, 3), got {start.shape}")
    fg = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    active = graph.active
    for n in np.flatnonzero(active):
        values.insert(int(n), gtsam.Pose2(*start[n]))
    for n in np.flatnonzero(graph.fixed & active):
        fg.add(gtsam.PriorFactorPose2(int(n), gtsam.Pose2(*start[n]),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 1e-9)))
    tables = graph.factor_tables()
    for (i, j), mu, w in zip(*tables["between"], strict=True):
        fg.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*mu),
                                        gtsam.noiseModel.Gaussian.SqrtInformation(w)))
    for (a, b), mu, w, off in zip(*tables["observation"], strict=True):
        diag = np.diag(w)
        if np.any(off) or np.count_nonzero(w - np.diag(diag)) or np.any(diag == 0):
            raise ValueError("GTSAM check: robot observations must be full (range, bearing, "
                             "orientation) with diagonal noise and no pose offsets")
        sig = 1.0 / diag
        fg.add(gtsam.BearingRangeFactorPose2(int(a), int(b), gtsam.Rot2(mu[1]), mu[0],
                                             gtsam.noiseModel.Diagonal.Sigmas(sig[[1, 0]])))
        orient = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, diag[2] ** 2]))
        fg.add(gtsam.BetweenFactorPose2(int(a), int(b), gtsam.Pose2(0.0, 0.0, mu[2]), orient))
    for prior in graph.priors:
        fg.add(_prior_factor(gtsam, prior))
    return fg, values


def gtsam_solve(graph: PoseGraph, start: np.ndarray, max_iterations: int = 100,
                rel_tol: float = 1e-12) -> GtsamResult:
    """Solve ``graph`` from ``start`` with GTSAM's Levenberg-Marquardt (``graph`` unchanged)."""
    import gtsam

    fg, values = to_gtsam(graph, start)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(rel_tol)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(int(max_iterations))
    t0, c0 = time.perf_counter(), time.process_time()
    optimizer = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    result = optimizer.optimize()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    poses = np.array(start, dtype=float)
    for n in np.flatnonzero(graph.active):
        p = result.atPose2(int(n))
        poses[n] = (p.x(), p.y(), p.theta())
    return GtsamResult(poses, float(fg.error(result)), int(optimizer.iterations()), seconds, cpu)


def dead_reckoning(graph: PoseGraph) -> np.ndarray:
    """Node poses chained through the motion factors from each robot's first node.

    A start for the batch solvers that uses no robot observation: the first node of
    each robot keeps its current pose, every later one is its predecessor composed
    with the measured motion.
    """
    poses = graph.poses.copy()
    ij, mu, _ = graph.factor_tables()["between"]
    for (i, j), m in sorted(zip(map(tuple, ij), mu, strict=True), key=lambda t: t[0][1]):
        poses[j] = compose(poses[i], m)
    return poses
