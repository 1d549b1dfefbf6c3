"""Solving the pose graph: Levenberg-Marquardt, marginal covariances, marginalization."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from estimators.pose_graph.graph import LinearPrior, PoseGraph


@dataclass
class SolveResult:
    """Outcome of :func:`optimize`."""

    initial_cost: float
    cost: float
    iterations: int
    converged: bool
    n_residuals: int
    n_variables: int
    history: list[float] = field(default_factory=list)
    factor: object | None = field(default=None, repr=False)
    """Factorized information of the last accepted step (lightly damped, at the estimate
    before it) when that step was the final one; reusable by :func:`marginal_covariances`
    as long as the graph is not changed."""


def _ensure_gauge(graph: PoseGraph) -> None:
    if not graph.priors and not np.any(graph.fixed & graph.active):
        first = int(np.flatnonzero(graph.active)[0])
        graph.set_fixed(first)


class _Factor:
    """Cholesky (dense) or LU (sparse) factorization of a symmetric positive matrix."""

    def __init__(self, h: np.ndarray | sp.csc_matrix) -> None:
        self.dense = isinstance(h, np.ndarray)
        self.scale = max(float(np.abs(h.diagonal()).max(initial=0.0)), 1e-300)
        try:
            if self.dense:
                self._f = sla.cho_factor(h, lower=False, check_finite=False)
            else:
                self._f = spla.splu(h, permc_spec="MMD_AT_PLUS_A")
        except (np.linalg.LinAlgError, RuntimeError) as exc:
            raise np.linalg.LinAlgError(str(exc)) from None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        if self.dense:
            return sla.cho_solve(self._f, rhs, check_finite=False)
        return self._f.solve(rhs)


def _add_diagonal(
    h: np.ndarray | sp.csc_matrix, values: np.ndarray, diag_slots: np.ndarray | None
) -> np.ndarray | sp.csc_matrix:
    """``h + diag(values)`` (a copy; sparse ``h`` keeps its pattern, diagonal included)."""
    if isinstance(h, np.ndarray):
        out = h.copy()
        out[np.diag_indices_from(out)] += values
        return out
    out = h.copy()
    out.data[diag_slots] += values
    return out


_MIN_DAMPING = 1e-6
"""Damping tried first when an undamped (Gauss-Newton) step fails."""


def optimize(
    graph: PoseGraph,
    max_iterations: int = 50,
    rel_tol: float = 1e-12,
    step_tol: float = 1e-10,
    initial_lambda: float = 0.0,
    dense: bool | None = None,
) -> SolveResult:
    """Minimize ``U(X)`` in place by Levenberg-Marquardt on the normal equations.

    Each iteration assembles ``H = J^T J`` and ``g = J^T r`` from the analytic
    factor Jacobians and solves ``(H + lambda diag(H)) delta = -g`` (dense Cholesky
    for small problems, sparse LU otherwise; see :meth:`PoseGraph.normal_equations`).
    ``lambda`` starts at ``initial_lambda`` (0: a Gauss-Newton step is tried first),
    grows tenfold (from at least 1e-6) while a step fails to lower the cost or ``H``
    is singular, and shrinks tenfold (back to 0) after each success. Stops when the
    relative cost decrease falls below ``rel_tol``, the largest step component below
    ``step_tol``, or after ``max_iterations`` linearizations.
    If the graph has no fixed node and no prior, its first active node is fixed.
    """
    if max_iterations < 0:
        raise ValueError(f"max_iterations must be >= 0, got {max_iterations!r}")
    if not np.any(graph.active):
        raise ValueError("the graph has no active node")
    _ensure_gauge(graph)
    h, g, cost = graph.normal_equations(dense=dense)
    if not np.isfinite(cost):
        raise ValueError(f"the cost at the initial estimate is not finite ({cost!r})")
    diag_slots = None if isinstance(h, np.ndarray) else graph.diagonal_slots()
    initial = cost
    history = [cost]
    lam = initial_lambda
    n_var = len(g)
    converged = n_var == 0
    it = 0
    lam_used = lam
    while not converged and it < max_iterations:
        it += 1
        diag = h.diagonal()
        damp = np.maximum(diag, 1e-9 * max(diag.max(initial=0.0), 1.0))
        improved = False
        factor = None
        while lam < 1e12:
            try:
                factor = _Factor(_add_diagonal(h, lam * damp, diag_slots))
                delta = -factor.solve(g)
            except np.linalg.LinAlgError:  # numerically singular: raise damping
                lam = max(10.0 * lam, _MIN_DAMPING)
                continue
            trial = graph.retract(delta)
            new_cost = graph.cost(trial)
            if np.isfinite(new_cost) and new_cost <= cost:
                improved = True
                break
            lam = max(10.0 * lam, _MIN_DAMPING)
        if not improved:
            converged = True  # no descent possible at machine precision: at a minimum
            factor = None
            break
        graph.poses[:] = trial
        decrease = cost - new_cost
        history.append(new_cost)
        lam_used = lam
        lam = lam / 10.0 if lam >= 10.0 * _MIN_DAMPING else 0.0
        if decrease <= rel_tol * max(new_cost, 1e-300) or np.max(np.abs(delta)) < step_tol:
            cost = new_cost
            converged = True
            break
        h, g, cost = graph.normal_equations(dense=dense)
    if it == 0 or lam_used > 0.0:  # no step taken, or a damped factor (not H itself)
        factor = None
    return SolveResult(initial, cost, it, converged, graph.n_residuals, n_var, history, factor)



def marginal_covariances(
    graph: PoseGraph, nodes: np.ndarray, factor: object | None = None
) -> np.ndarray:
    """3x3 marginal covariances of ``nodes`` from the inverse information matrix.

    Fixed nodes get a zero covariance. ``factor`` (``SolveResult.factor`` of the
    last :func:`optimize` on this unchanged graph) saves re-linearizing and
    re-factorizing. Raises ``ValueError`` if the information matrix is singular
    (a node not tied to the anchor or a prior).
    """
    nodes = graph.check_nodes(nodes)
    var = graph.variable_index()
    out = np.zeros((len(nodes), 3, 3))
    free = np.flatnonzero(var[nodes] >= 0)
    if len(free) == 0:
        return out
    n_var = 3 * int(var.max(initial=-1) + 1)
    cols = (3 * var[nodes[free]][:, None] + np.arange(3)).ravel()
    rhs = np.zeros((n_var, len(cols)))
    rhs[cols, np.arange(len(cols))] = 1.0
    try:
        if not isinstance(factor, _Factor):
            h = graph.normal_equations()[0]
            factor = _Factor(h)
        sol = factor.solve(rhs)
    except np.linalg.LinAlgError as exc:
        raise ValueError(f"information matrix is singular (gauge not fixed?): {exc}") from None
    block = sol[cols].reshape(len(free), 3, len(free), 3)
    out[free] = block[np.arange(len(free)), :, np.arange(len(free)), :]
    out = 0.5 * (out + out.transpose(0, 2, 1))
    eig = np.linalg.eigvalsh(out[free])
    if not np.all(np.isfinite(out)) or np.any(eig <= 0) or np.any(eig.max(1) * factor.scale > 1e14):
        raise ValueError("information matrix is singular (gauge not fixed?)")
    return out


def marginalize(graph: PoseGraph, nodes: np.ndarray, rel_eig_tol: float = 1e-12) -> None:
    """Remove ``nodes`` and fold every factor touching them into one dense prior.

    The factors are linearized at the current estimate and the removed variables
    eliminated by the Schur complement, giving a Gaussian prior on the Markov
    blanket (the remaining nodes those factors touch). Fixed nodes among ``nodes``
    are constants, so their factors become priors that keep the gauge anchored.
    """
    drop = graph.check_nodes(nodes)
    if len(drop) == 0:
        return
    dropped = np.zeros(graph.n_nodes, bool)
    dropped[drop] = True
    hit = graph.factors_touching(dropped)
    touched = np.unique(np.concatenate(graph.selection_nodes(hit) + [drop]))
    sub = graph.subgraph(touched, hit)
    h, g, _ = sub.normal_equations(dense=True)
    var = sub.variable_index()
    is_drop = dropped[touched]
    d_cols = (3 * var[is_drop & (var >= 0)][:, None] + np.arange(3)).ravel()
    keep_nodes = touched[~is_drop & (var >= 0)]
    k_cols = (3 * var[~is_drop & (var >= 0)][:, None] + np.arange(3)).ravel()
    h_kk = h[np.ix_(k_cols, k_cols)]
    g_k = g[k_cols]
    if len(d_cols):
        h_dd = h[np.ix_(d_cols, d_cols)]
        h_dk = h[np.ix_(d_cols, k_cols)]
        rhs = np.column_stack([h_dk, g[d_cols]])
        sol = np.linalg.lstsq(h_dd, rhs, rcond=1e-14)[0]
        h_kk = h_kk - h_dk.T @ sol[:, :-1]
        g_k = g_k - h_dk.T @ sol[:, -1]

    graph.remove(hit, drop)
    if len(k_cols) == 0:
        return
    h_kk = 0.5 * (h_kk + h_kk.T)
    w, v = np.linalg.eigh(h_kk)
    ok = w > rel_eig_tol * max(w.max(initial=0.0), 1e-300)
    if not np.any(ok):
        return
    sw = np.sqrt(w[ok])
    a_mat = sw[:, None] * v[:, ok].T
    b_vec = (v[:, ok].T @ g_k) / sw
    graph.append_prior(LinearPrior(keep_nodes, graph.poses[keep_nodes].copy(), a_mat, b_vec))

