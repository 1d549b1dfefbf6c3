"""Planar pose graph for team localization by maximum likelihood (Howard, Mataric, Sukhatme).

Nodes are pose estimates ``(x, y, heading)`` of one robot at one sampled time.
Factors (the paper's *observations*) are Gaussian and the negative log
likelihood is ``U(X) = sum 0.5 * ||W (mu - G(x_a, x_b))||^2`` with ``W`` the
square-root information of the factor (``W^T W = Sigma^-1``).

Three kinds of factor:

* **Motion** (``add_between``): the measured pose of node ``j`` relative to node
  ``i`` of the same robot (odometry integrated over a window). The residual is
  the SE(2) logarithm ``Log(T_mu^-1 T_i^-1 T_j)``, the same function as GTSAM's
  ``BetweenFactorPose2``. It is smooth everywhere, in particular when the robot
  did not move (the paper's range/bearing form is singular at ``r = 0`` because
  the bearing of a zero displacement is undefined; the Cartesian/SE(2) form has
  no such point). The covariance is given in the frame of node ``i``.
* **Robot observation** (``add_observation``): range, bearing and orientation of
  robot ``b`` seen from robot ``a`` (paper Eq. 15 form), any subset of the three
  components, optionally with known pose offsets ``o_a``, ``o_b`` applied to the
  nodes (``G(x_a + o_a, x_b + o_b)``, used online to attach an observation taken
  between two sampled times). Angles are wrapped in the residual. Near ``r = 0``
  the range/bearing derivatives are evaluated with ``max(r, min_range)`` so they
  stay finite (callers should also drop the bearing of a measurement whose range
  is ~0, as :class:`estimators.mle_online.TeamMLE` does).
* **Linear prior** (``add_prior``): ``||A (x_S - x0_S) + b||^2`` over a set of
  nodes ``S``; pose priors and the result of marginalization are of this kind.

Gauge freedom: only relative poses are observable. Nodes flagged ``fixed`` are
constants; if a graph has neither a fixed node nor a prior, :func:`optimize`
fixes its first active node.

The solver (:func:`optimize`) is Levenberg-Marquardt (Marquardt's diagonal
scaling) on the normal equations ``J^T J delta = -J^T r``, assembled block by
block from analytic factor Jacobians (:meth:`PoseGraph.linearize` gives the
sparse ``J`` itself); they are solved by sparse LU (``scipy.sparse``) for large,
sparse problems and by dense Cholesky for small or well-filled ones (e.g. a
sliding window with a dense marginalization prior). Updates are additive on
``(x, y, heading)`` with the heading wrapped. On the same graph and start it
reaches the same minimum as GTSAM's Levenberg-Marquardt (see
``scripts/bench/mle.py``). :func:`marginal_covariances` reads 3x3 blocks of the
inverse information matrix; :func:`marginalize` replaces nodes by a dense prior
on their Markov blanket (Schur complement at the current estimate).

Modules: :mod:`~estimators.pose_graph.se2` (SE(2) helpers, factor residuals and
their Jacobians), :mod:`~estimators.pose_graph.graph` (:class:`PoseGraph`),
:mod:`~estimators.pose_graph.solver` (:func:`optimize`, :func:`marginal_covariances`,
:func:`marginalize`) and :mod:`~estimators.pose_graph.synthetic` (random team graphs
and sensor streams with ground truth, for tests and benchmarks). Every public name is
importable from this package.
"""

from estimators.pose_graph.graph import (
    COMPONENTS,
    DENSE_FILL_MAX_VARIABLES,
    DENSE_MAX_VARIABLES,
    FactorSelection,
    LinearPrior,
    PoseGraph,
    check_observation,
)
from estimators.pose_graph.se2 import (
    DEFAULT_MIN_RANGE,
    between,
    between_residual,
    compose,
    observation_residual,
    se2_exp,
    se2_log_coefficients,
    sqrt_information,
)
from estimators.pose_graph.solver import (
    SolveResult,
    marginal_covariances,
    marginalize,
    optimize,
)
from estimators.pose_graph.synthetic import (
    PairSensing,
    SyntheticTeam,
    TeamStream,
    observe_pairs,
    random_team_graph,
    simulate_team_stream,
)

__all__ = [
    "COMPONENTS",
    "DEFAULT_MIN_RANGE",
    "DENSE_FILL_MAX_VARIABLES",
    "DENSE_MAX_VARIABLES",
    "FactorSelection",
    "LinearPrior",
    "PairSensing",
    "PoseGraph",
    "SolveResult",
    "SyntheticTeam",
    "TeamStream",
    "between",
    "between_residual",
    "check_observation",
    "compose",
    "marginal_covariances",
    "marginalize",
    "observation_residual",
    "observe_pairs",
    "optimize",
    "random_team_graph",
    "se2_exp",
    "se2_log_coefficients",
    "simulate_team_stream",
    "sqrt_information",
]
