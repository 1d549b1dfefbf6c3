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
``scripts/_bench_mle.py``). :func:`marginal_covariances` reads 3x3 blocks of the
inverse information matrix; :func:`marginalize` replaces nodes by a dense prior
on their Markov blanket (Schur complement at the current estimate).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from estimators.geometry import wrap_angle
from estimators.relative_metrics import relative_pose_matrix

COMPONENTS = "rbo"
"""Letters naming the components of a robot observation: range, bearing, orientation."""

DEFAULT_MIN_RANGE = 1e-6
"""Floor on the range used in observation derivatives (metres)."""

DENSE_MAX_VARIABLES = 450
"""Problems with at most this many variables use dense Cholesky, larger ones sparse LU..."""

DENSE_FILL_MAX_VARIABLES = 3000
"""...unless ``H`` is more than 5 % full and has at most this many variables."""


def _cat(parts: list[np.ndarray], dtype: type) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(0, dtype)


class _Columns:
    """A growable structure of numpy arrays sharing their first axis (O(1) amortized append)."""

    def __init__(self, specs: dict[str, tuple[tuple[int, ...], type]]) -> None:
        self._specs = specs
        self._data = {k: np.zeros((8, *shape), dtype=dt) for k, (shape, dt) in specs.items()}
        self.n = 0

    def append(self, **values: np.ndarray) -> int:
        if self.n == len(next(iter(self._data.values()))):
            for k, arr in self._data.items():
                grown = np.zeros((2 * len(arr), *arr.shape[1:]), dtype=arr.dtype)
                grown[: self.n] = arr[: self.n]
                self._data[k] = grown
        for k in self._specs:
            self._data[k][self.n] = values[k]
        self.n += 1
        return self.n - 1

    def __getitem__(self, key: str) -> np.ndarray:
        return self._data[key][: self.n]

    def keep(self, mask: np.ndarray) -> None:
        """Keep only rows where ``mask`` is true (order preserved)."""
        kept = int(np.count_nonzero(mask))
        for arr in self._data.values():
            arr[:kept] = arr[: self.n][mask]
        self.n = kept


@dataclass
class LinearPrior:
    """Gaussian factor ``0.5 ||A (x_S - x0) + b||^2`` over nodes ``S`` (angles wrapped)."""

    nodes: np.ndarray
    x0: np.ndarray
    A: np.ndarray
    b: np.ndarray


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


def _check_pose(pose: np.ndarray, name: str) -> np.ndarray:
    pose = np.array(pose, dtype=float)  # a copy: callers' arrays are never modified
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name} must be 3 finite numbers (x, y, heading), got {pose!r}")
    return pose


def sqrt_information(cov: np.ndarray, name: str = "cov") -> np.ndarray:
    """Lower-triangular ``W`` with ``W^T W = cov^-1``; raises ``ValueError`` if not SPD."""
    cov = np.asarray(cov, dtype=float)
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or not np.all(np.isfinite(cov)):
        raise ValueError(f"{name} must be a finite square matrix, got {cov!r}")
    if np.abs(cov - cov.T).max(initial=0.0) > 1e-9 * np.abs(cov).max(initial=0.0) + 1e-15:
        raise ValueError(f"{name} must be symmetric, got {cov!r}")
    try:
        lower = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be positive definite, got {cov!r}") from None
    # cov = L L^T  =>  cov^-1 = L^-T L^-1 = W^T W with W = L^-1.
    return np.linalg.solve(lower, np.eye(len(cov)))


def se2_log_coefficients(psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``a(psi) = (psi/2) cot(psi/2)`` and its derivative (series near 0)."""
    psi = np.asarray(psi, dtype=float)
    small = np.abs(psi) < 1e-4
    half = np.where(small, 1.0, psi / 2.0)
    tan_half = np.tan(half)
    a = np.where(small, 1.0 - psi**2 / 12.0, half / np.where(small, 1.0, tan_half))
    # d/dpsi [h cot h] with h = psi/2: 0.5 * (cot h - h / sin^2 h)
    sin_half = np.sin(half)
    da = np.where(
        small, -psi / 6.0, 0.5 * (1.0 / np.where(small, 1.0, tan_half) - half / sin_half**2)
    )
    return a, da


def between_residual(
    xi: np.ndarray, xj: np.ndarray, mu: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """SE(2) log residual ``Log(T_mu^-1 T_i^-1 T_j)`` and its Jacobians w.r.t. ``xi`` and ``xj``.

    Shapes: ``xi, xj, mu`` are ``(m, 3)``; returns ``e (m, 3)``, ``Ji, Jj (m, 3, 3)``.
    """
    c, s = np.cos(xi[:, 2]), np.sin(xi[:, 2])
    dx, dy = xj[:, 0] - xi[:, 0], xj[:, 1] - xi[:, 1]
    ux, uy = c * dx + s * dy, -s * dx + c * dy
    cm, sm = np.cos(mu[:, 2]), np.sin(mu[:, 2])
    px, py = ux - mu[:, 0], uy - mu[:, 1]
    wx, wy = cm * px + sm * py, -sm * px + cm * py
    psi = wrap_angle(xj[:, 2] - xi[:, 2] - mu[:, 2])
    a, da = se2_log_coefficients(psi)
    b = 0.5 * psi
    e = np.stack([a * wx + b * wy, -b * wx + a * wy, psi], axis=-1)

    m = len(xi)
    # d e_xy / d w = M = [[a, b], [-b, a]];  d w / d u = Rm^T;  d e_xy / d psi = M' w
    mr = np.empty((m, 2, 2))  # M @ Rm^T
    mr[:, 0, 0] = a * cm - b * sm
    mr[:, 0, 1] = a * sm + b * cm
    mr[:, 1, 0] = -b * cm - a * sm
    mr[:, 1, 1] = -b * sm + a * cm
    dpsi = np.stack([da * wx + 0.5 * wy, -0.5 * wx + da * wy], axis=-1)  # (m, 2)
    # d u / d xi = [[-c, -s, uy], [s, -c, -ux]];  d u / d xj = [[c, s, 0], [-s, c, 0]]
    du_dpj = np.empty((m, 2, 2))
    du_dpj[:, 0, 0], du_dpj[:, 0, 1] = c, s
    du_dpj[:, 1, 0], du_dpj[:, 1, 1] = -s, c
    mrr = mr @ du_dpj  # d e_xy / d p_j
    ji = np.zeros((m, 3, 3))
    jj = np.zeros((m, 3, 3))
    jj[:, :2, :2] = mrr
    jj[:, :2, 2] = dpsi
    jj[:, 2, 2] = 1.0
    ji[:, :2, :2] = -mrr
    ji[:, :2, 2] = mr[:, :, 0] * uy[:, None] - mr[:, :, 1] * ux[:, None] - dpsi
    ji[:, 2, 2] = -1.0
    return e, ji, jj


def _offset_pose(x: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``x (+) off`` (offset in the frame of ``x``) and its Jacobian w.r.t. ``x``."""
    c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
    ox, oy = off[:, 0], off[:, 1]
    out = np.stack([x[:, 0] + c * ox - s * oy, x[:, 1] + s * ox + c * oy, x[:, 2] + off[:, 2]], -1)
    jac = np.zeros((len(x), 3, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = jac[:, 2, 2] = 1.0
    jac[:, 0, 2] = -s * ox - c * oy
    jac[:, 1, 2] = c * ox - s * oy
    return out, jac


def observation_residual(
    xa: np.ndarray,
    xb: np.ndarray,
    mu: np.ndarray,
    off_a: np.ndarray | None = None,
    off_b: np.ndarray | None = None,
    min_range: float = DEFAULT_MIN_RANGE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residual ``G(xa (+) off_a, xb (+) off_b) - mu`` (range, bearing, orientation) and Jacobians.

    Angles are wrapped. Derivatives use ``max(r, min_range)``, so they stay finite at
    ``r = 0``; closer than ``min_range`` they are taken along the measured bearing.
    Shapes as in :func:`between_residual`.
    """
    m = len(xa)
    if off_a is None:
        off_a = np.zeros((m, 3))
    if off_b is None:
        off_b = np.zeros((m, 3))
    pa, ta = _offset_pose(xa, off_a)
    pb, tb = _offset_pose(xb, off_b)
    dx, dy = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    r = np.hypot(dx, dy)
    rr = np.maximum(r, min_range)
    e = np.stack(
        [
            r - mu[:, 0],
            wrap_angle(np.arctan2(dy, dx) - pa[:, 2] - mu[:, 1]),
            wrap_angle(pb[:, 2] - pa[:, 2] - mu[:, 2]),
        ],
        axis=-1,
    )
    # Below min_range the direction is undefined: differentiate as if b sat
    # min_range away along the measured bearing (a subgradient of the range cone),
    # so coincident robots still constrain each other instead of giving zero rows.
    close = r < min_range
    if np.any(close):
        phi = pa[close, 2] + mu[close, 1]
        dx, dy = dx.copy(), dy.copy()
        dx[close], dy[close] = min_range * np.cos(phi), min_range * np.sin(phi)
    ga = np.zeros((m, 3, 3))
    ga[:, 0, 0], ga[:, 0, 1] = -dx / rr, -dy / rr
    ga[:, 1, 0], ga[:, 1, 1], ga[:, 1, 2] = dy / rr**2, -dx / rr**2, -1.0
    ga[:, 2, 2] = -1.0
    gb = np.zeros((m, 3, 3))
    gb[:, 0, 0], gb[:, 0, 1] = dx / rr, dy / rr
    gb[:, 1, 0], gb[:, 1, 1] = -dy / rr**2, dx / rr**2
    gb[:, 2, 2] = 1.0
    return e, ga @ ta, gb @ tb


class PoseGraph:
    """Nodes (poses of robots at sampled times) and Gaussian factors between them.

    Node ids are stable integers; marginalized nodes become inactive but keep their
    last estimate. ``poses`` holds the current estimate of every node, ``(n, 3)``.
    """

    def __init__(self, min_range: float = DEFAULT_MIN_RANGE) -> None:
        if not min_range > 0:
            raise ValueError(f"min_range must be > 0, got {min_range!r}")
        self.min_range = float(min_range)
        self._nodes = _Columns(
            {
                "pose": ((3,), float),
                "robot": ((), int),
                "time": ((), float),
                "fixed": ((), bool),
                "active": ((), bool),
            }
        )
        self._between = _Columns({"ij": ((2,), int), "mu": ((3,), float), "W": ((3, 3), float)})
        self._obs = _Columns(
            {
                "ij": ((2,), int),
                "mu": ((3,), float),
                "W": ((3, 3), float),
                "off": ((2, 3), float),
                "dim": ((), int),
            }
        )
        self.priors: list[LinearPrior] = []
        self._version = 0
        self._cache_version = -1
        self._cache: dict = {}

    # ------------------------------------------------------------------ nodes
    @property
    def n_nodes(self) -> int:
        """Number of nodes ever added (active or not)."""
        return self._nodes.n

    @property
    def poses(self) -> np.ndarray:
        """Current estimates of all nodes, ``(n, 3)`` (a view: writes go to the graph)."""
        return self._nodes["pose"]

    @property
    def node_robot(self) -> np.ndarray:
        """Robot index of each node."""
        return self._nodes["robot"]

    @property
    def node_time(self) -> np.ndarray:
        """Time stamp of each node (``nan`` if not given)."""
        return self._nodes["time"]

    @property
    def fixed(self) -> np.ndarray:
        """Boolean mask of nodes held constant."""
        return self._nodes["fixed"]

    @property
    def active(self) -> np.ndarray:
        """Boolean mask of nodes still in the graph (not marginalized)."""
        return self._nodes["active"]

    def add_node(
        self, pose: np.ndarray, robot: int = -1, time: float = np.nan, fixed: bool = False
    ) -> int:
        """Add a pose estimate (initial guess ``pose``); returns its node id."""
        pose = _check_pose(pose, "pose")
        pose[2] = wrap_angle(pose[2])
        self._version += 1
        return self._nodes.append(pose=pose, robot=robot, time=time, fixed=fixed, active=True)

    def set_fixed(self, node: int, fixed: bool = True) -> None:
        """Hold node ``node`` constant (anchor the gauge) or release it."""
        self._check_node(node)
        self._nodes["fixed"][node] = fixed
        self._version += 1

    def _check_node(self, node: int) -> int:
        if not (0 <= int(node) < self.n_nodes) or not self.active[int(node)]:
            raise ValueError(f"node {node!r} is not an active node of the graph")
        return int(node)

    # ---------------------------------------------------------------- factors
    @property
    def n_between(self) -> int:
        """Number of motion factors."""
        return self._between.n

    @property
    def n_observations(self) -> int:
        """Number of robot-observation factors."""
        return self._obs.n

    def add_between(self, i: int, j: int, delta: np.ndarray, cov: np.ndarray) -> None:
        """Motion factor: pose of ``j`` relative to ``i`` measured as ``delta`` (in ``i``'s frame).

        ``cov`` (3x3) is the covariance of ``delta`` expressed in the frame of node ``i``
        (as produced by integrating odometry); it is rotated into the tangent space of
        the measurement internally.
        """
        i, j = self._check_node(i), self._check_node(j)
        if i == j:
            raise ValueError(f"a motion factor needs two distinct nodes, got i = j = {i}")
        delta = _check_pose(delta, "delta")
        w = sqrt_information(cov, "cov")
        c, s = np.cos(delta[2]), np.sin(delta[2])
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # e = rot^T (.)
        self._between.append(ij=(i, j), mu=delta, W=w @ rot)
        self._version += 1

    def add_observation(
        self,
        a: int,
        b: int,
        measurement: np.ndarray,
        std: np.ndarray | None = None,
        cov: np.ndarray | None = None,
        components: str = COMPONENTS,
        offset_a: np.ndarray | None = None,
        offset_b: np.ndarray | None = None,
    ) -> None:
        """Robot observation: ``b`` seen from ``a`` at (range, bearing, orientation).

        ``components`` names the measured subset (e.g. ``"rb"`` for range and bearing);
        ``measurement`` and ``std`` (or a full ``cov``) follow that order. Optional
        ``offset_a``/``offset_b`` are known poses relative to the nodes at which the
        measurement was really taken.
        """
        a, b = self._check_node(a), self._check_node(b)
        if a == b:
            raise ValueError(f"a robot observation needs two distinct nodes, got a = b = {a}")
        if not components or any(ch not in COMPONENTS for ch in components) or len(
            set(components)
        ) != len(components):
            raise ValueError(f"components must be a non-empty subset of 'rbo', got {components!r}")
        k = len(components)
        meas = np.asarray(measurement, dtype=float).reshape(-1)
        if meas.shape != (k,) or not np.all(np.isfinite(meas)):
            raise ValueError(f"measurement must be {k} finite numbers, got {measurement!r}")
        if "r" in components and meas[components.index("r")] < 0:
            raise ValueError(f"measured range must be >= 0, got {measurement!r}")
        if (std is None) == (cov is None):
            raise ValueError("give exactly one of std and cov")
        if std is not None:
            std = np.asarray(std, dtype=float).reshape(-1)
            if std.shape != (k,) or not np.all(np.isfinite(std)) or np.any(std <= 0):
                raise ValueError(f"std must be {k} positive numbers, got {std!r}")
            cov = np.diag(std**2)
        w_sub = sqrt_information(np.asarray(cov, dtype=float), "cov")
        if w_sub.shape != (k, k):
            raise ValueError(f"cov must be {k}x{k}, got shape {w_sub.shape}")
        idx = [COMPONENTS.index(ch) for ch in components]
        mu = np.zeros(3)
        mu[idx] = meas
        w = np.zeros((3, 3))
        w[np.ix_(range(k), idx)] = w_sub
        off = np.zeros((2, 3))
        if offset_a is not None:
            off[0] = _check_pose(offset_a, "offset_a")
        if offset_b is not None:
            off[1] = _check_pose(offset_b, "offset_b")
        self._obs.append(ij=(a, b), mu=mu, W=w, off=off, dim=k)
        self._version += 1

    def add_prior(
        self, nodes: np.ndarray, x0: np.ndarray, A: np.ndarray, b: np.ndarray | None = None
    ) -> None:
        """Linear prior ``0.5 ||A (x_S (-) x0) + b||^2`` over ``nodes`` (``A`` is ``(q, 3|S|)``)."""
        nodes = np.asarray([self._check_node(n) for n in np.atleast_1d(nodes)], dtype=int)
        x0 = np.asarray(x0, dtype=float).reshape(len(nodes), 3)
        A = np.asarray(A, dtype=float)
        if A.ndim != 2 or A.shape[1] != 3 * len(nodes) or not np.all(np.isfinite(A)):
            raise ValueError(f"A must be finite with {3 * len(nodes)} columns, got {A.shape}")
        b = np.zeros(len(A)) if b is None else np.asarray(b, dtype=float).reshape(-1)
        if b.shape != (len(A),) or not np.all(np.isfinite(b)):
            raise ValueError(f"b must be {len(A)} finite numbers, got {b!r}")
        self.priors.append(LinearPrior(nodes, x0.copy(), A.copy(), b.copy()))
        self._version += 1

    def add_pose_prior(self, node: int, pose: np.ndarray, std: np.ndarray) -> None:
        """Independent Gaussian prior on one node: mean ``pose``, std devs ``std`` (3,)."""
        std = np.asarray(std, dtype=float).reshape(-1)
        if std.shape != (3,) or not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise ValueError(f"std must be 3 positive numbers, got {std!r}")
        self.add_prior([node], _check_pose(pose, "pose"), np.diag(1.0 / std))

    def factor_tables(self) -> dict[str, tuple[np.ndarray, ...]]:
        """Copies of the factor arrays: ``"between"``: ``(ij, mu, W)`` and ``"observation"``:
        ``(ij, mu, W, offsets)``, with ``W`` the 3x3 square-root information of each residual
        (zero rows for unmeasured components; motion ``W`` in the tangent space of ``mu``).
        """
        b, o = self._between, self._obs
        return {
            "between": (b["ij"].copy(), b["mu"].copy(), b["W"].copy()),
            "observation": (o["ij"].copy(), o["mu"].copy(), o["W"].copy(), o["off"].copy()),
        }

    @property
    def n_residuals(self) -> int:
        """Number of scalar measurements (residual rows that carry information)."""
        return int(3 * self.n_between + self._obs["dim"].sum() + sum(len(p.b) for p in self.priors))

    # ------------------------------------------------------------- structure
    def variable_index(self) -> np.ndarray:
        """Column block of each node in the Jacobian (``-1`` for fixed or inactive nodes)."""
        free = self.active & ~self.fixed
        index = np.full(self.n_nodes, -1)
        index[free] = np.arange(np.count_nonzero(free))
        return index

    def _structure(self, part: str = "base") -> dict:
        """Index patterns for the current graph, built lazily and cached until it changes.

        ``part`` is ``"base"`` (variable index, normal-equation keys), ``"sparse"`` (CSC
        pattern of ``H``) or ``"jacobian"`` (CSR pattern of ``J``).
        """
        if self._cache_version != self._version:
            self._cache = {}
            self._cache_version = self._version
        st = self._cache
        if "var" not in st:
            var = self.variable_index()
            n = 3 * int(var.max(initial=-1) + 1)
            h_keys, h_valid, g_cols, g_valid = [], [], [], []
            for nodes, _ in self._group_shapes():
                m, k = nodes.shape
                cols = (3 * var[nodes][:, :, None] + np.arange(3)).reshape(m, 3 * k)
                ok = np.repeat(var[nodes] >= 0, 3, axis=1)
                pair_ok = ok[:, :, None] & ok[:, None, :]
                h_valid.append(pair_ok.ravel())
                h_keys.append((cols[:, None, :] * n + cols[:, :, None])[pair_ok])
                g_valid.append(ok.ravel())
                g_cols.append(cols[ok])
            st.update(
                var=var,
                n_var=n,
                h_valid=_cat(h_valid, bool),
                h_keys=_cat(h_keys, np.int64),
                g_valid=_cat(g_valid, bool),
                g_cols=_cat(g_cols, np.int64),
                diag_keys=np.arange(n) * (n + 1),
            )
        if part == "sparse" and "h_indptr" not in st:
            n = st["n_var"]
            keys = np.concatenate([st["h_keys"], st["diag_keys"]])
            uniq, inverse = np.unique(keys, return_inverse=True)
            st.update(
                h_inverse=inverse[: len(st["h_keys"])],
                h_indices=uniq % max(n, 1),
                h_indptr=np.searchsorted(uniq // max(n, 1), np.arange(n + 1)),
                h_diag=np.searchsorted(uniq, st["diag_keys"]),
                h_nnz=len(uniq),
            )
        if part == "jacobian" and "j_perm" not in st:
            var, n = st["var"], st["n_var"]
            j_rows, j_cols = [], []
            row0 = 0
            for nodes, dim in self._group_shapes():
                m, k = nodes.shape
                cols = (3 * var[nodes][:, :, None] + np.arange(3)).reshape(m, 3 * k)
                ok = np.repeat(var[nodes] >= 0, 3, axis=1)
                rows = row0 + dim * np.arange(m)[:, None, None] + np.arange(dim)[None, :, None]
                j_rows.append(np.broadcast_to(rows, (m, dim, 3 * k)).ravel())
                j_cols.append(np.where(ok, cols, -1)[:, None, :].repeat(dim, 1).ravel())
                row0 += m * dim
            rows_a, cols_a = _cat(j_rows, np.int64), _cat(j_cols, np.int64)
            keep = cols_a >= 0
            order = sp.csr_matrix(
                (np.arange(1, keep.sum() + 1, dtype=float), (rows_a[keep], cols_a[keep])),
                shape=(row0, n),
            )
            order.sort_indices()
            st.update(
                n_rows=row0,
                j_keep=keep,
                j_indices=order.indices.copy(),
                j_indptr=order.indptr.copy(),
                j_perm=order.data.astype(np.int64) - 1,
            )
        return st

    # ------------------------------------------------------------ evaluation
    def _group_shapes(self) -> list[tuple[np.ndarray, int]]:
        """Node ids ``(m, k)`` and residual size of each factor group, in evaluation order."""
        out = []
        if self._between.n:
            out.append((self._between["ij"], 3))
        if self._obs.n:
            out.append((self._obs["ij"], 3))
        out += [(p.nodes[None, :], len(p.b)) for p in self.priors]
        return out

    def _terms(self, poses: np.ndarray, jacobian: bool) -> list[tuple[np.ndarray, np.ndarray]]:
        """Whitened residuals ``(m, d)`` and Jacobians ``(m, d, 3k)`` of each factor group."""
        out = []
        if self._between.n:
            ij = self._between["ij"]
            e, ji, jj = between_residual(poses[ij[:, 0]], poses[ij[:, 1]], self._between["mu"])
            w = self._between["W"]
            jac = w @ np.concatenate([ji, jj], axis=2) if jacobian else None
            out.append((np.einsum("mij,mj->mi", w, e), jac))
        if self._obs.n:
            ij, off = self._obs["ij"], self._obs["off"]
            e, ja, jb = observation_residual(
                poses[ij[:, 0]], poses[ij[:, 1]], self._obs["mu"], off[:, 0], off[:, 1],
                self.min_range,
            )
            w = self._obs["W"]
            jac = w @ np.concatenate([ja, jb], axis=2) if jacobian else None
            out.append((np.einsum("mij,mj->mi", w, e), jac))
        for prior in self.priors:
            d = poses[prior.nodes] - prior.x0
            d[:, 2] = wrap_angle(d[:, 2])
            out.append(((prior.A @ d.ravel() + prior.b)[None], prior.A[None] if jacobian else None))
        return out

    def residuals(self, poses: np.ndarray | None = None) -> np.ndarray:
        """Whitened residual vector at ``poses`` (default: the current estimates)."""
        terms = self._terms(self.poses if poses is None else poses, jacobian=False)
        return np.concatenate([r.ravel() for r, _ in terms]) if terms else np.zeros(0)

    def cost(self, poses: np.ndarray | None = None) -> float:
        """``U(X) = 0.5 * sum of squared whitened residuals``."""
        r = self.residuals(poses)
        return 0.5 * float(r @ r)

    def linearize(self, poses: np.ndarray | None = None) -> tuple[np.ndarray, sp.csr_matrix]:
        """Whitened residuals and analytic sparse Jacobian w.r.t. the free node variables."""
        st = self._structure("jacobian")
        terms = self._terms(self.poses if poses is None else poses, jacobian=True)
        r = np.concatenate([t[0].ravel() for t in terms]) if terms else np.zeros(0)
        data = np.concatenate([t[1].ravel() for t in terms]) if terms else np.zeros(0)
        data = data[st["j_keep"]][st["j_perm"]]
        jac = sp.csr_matrix(
            (data, st["j_indices"], st["j_indptr"]), shape=(st["n_rows"], st["n_var"])
        )
        return r, jac

    def normal_equations(
        self, poses: np.ndarray | None = None, dense: bool | None = None
    ) -> tuple[np.ndarray | sp.csc_matrix, np.ndarray, float]:
        """Gauss-Newton information ``H = J^T J``, gradient ``g = J^T r`` and cost ``U``.

        Assembled block by block from the factors (no explicit ``J``). ``H`` is a dense
        array when ``dense`` (default: small or well-filled problems, see
        :data:`DENSE_MAX_VARIABLES`), else a ``scipy.sparse.csc_matrix``.
        """
        st = self._structure()
        n = st["n_var"]
        terms = self._terms(self.poses if poses is None else poses, jacobian=True)
        cost = 0.5 * sum(float(np.sum(r * r)) for r, _ in terms)
        hv = [(jac.transpose(0, 2, 1) @ jac).ravel() for _, jac in terms]
        gv = [np.einsum("mdi,md->mi", jac, r).ravel() for r, jac in terms]
        h_vals = np.concatenate(hv)[st["h_valid"]] if hv else np.zeros(0)
        g_vals = np.concatenate(gv)[st["g_valid"]] if gv else np.zeros(0)
        g = np.bincount(st["g_cols"], g_vals, minlength=n)
        if dense is None:
            fill = len(st["h_keys"]) / max(n * n, 1)  # upper bound on the density of H
            dense = n <= DENSE_MAX_VARIABLES or (n <= DENSE_FILL_MAX_VARIABLES and fill > 0.05)
        if dense:
            h = np.bincount(st["h_keys"], h_vals, minlength=n * n).reshape(n, n)
        else:
            st = self._structure("sparse")
            data = np.bincount(st["h_inverse"], h_vals, minlength=st["h_nnz"])
            h = sp.csc_matrix((data, st["h_indices"], st["h_indptr"]), shape=(n, n))
        return h, g, cost

    def retract(self, delta: np.ndarray) -> np.ndarray:
        """Poses after adding ``delta`` (length ``3 * n_free``) to the free nodes (a copy)."""
        var = self._structure()["var"]
        poses = self.poses.copy()
        free = var >= 0
        poses[free] += delta.reshape(-1, 3)[var[free]]
        poses[free, 2] = wrap_angle(poses[free, 2])
        return poses


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
    diag_slots = None if isinstance(h, np.ndarray) else graph._structure("sparse")["h_diag"]
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


def information_matrix(graph: PoseGraph) -> sp.csc_matrix:
    """Gauss-Newton information ``J^T J`` of the free variables at the current estimate."""
    return sp.csc_matrix(graph.normal_equations()[0])


def marginal_covariances(
    graph: PoseGraph, nodes: np.ndarray, factor: object | None = None
) -> np.ndarray:
    """3x3 marginal covariances of ``nodes`` from the inverse information matrix.

    Fixed nodes get a zero covariance. ``factor`` (``SolveResult.factor`` of the
    last :func:`optimize` on this unchanged graph) saves re-linearizing and
    re-factorizing. Raises ``ValueError`` if the information matrix is singular
    (a node not tied to the anchor or a prior).
    """
    nodes = np.asarray([graph._check_node(n) for n in np.atleast_1d(nodes)], dtype=int)
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
    drop = np.asarray([graph._check_node(n) for n in np.atleast_1d(nodes)], dtype=int)
    if len(drop) == 0:
        return
    dropped = np.zeros(graph.n_nodes, bool)
    dropped[drop] = True
    hit_b = dropped[graph._between["ij"]].any(axis=1)
    hit_o = dropped[graph._obs["ij"]].any(axis=1)
    hit_p = [bool(dropped[p.nodes].any()) for p in graph.priors]

    sub = PoseGraph(graph.min_range)
    touched = np.unique(
        np.concatenate(
            [graph._between["ij"][hit_b].ravel(), graph._obs["ij"][hit_o].ravel()]
            + [p.nodes for p, h in zip(graph.priors, hit_p, strict=True) if h]
            + [drop]
        )
    )
    local = {int(n): k for k, n in enumerate(touched)}
    for n in touched:
        sub.add_node(graph.poses[n], int(graph.node_robot[n]), float(graph.node_time[n]),
                     bool(graph.fixed[n]))
    for k in np.flatnonzero(hit_b):
        i, j = graph._between["ij"][k]
        sub._between.append(ij=(local[int(i)], local[int(j)]), mu=graph._between["mu"][k],
                            W=graph._between["W"][k])
    for k in np.flatnonzero(hit_o):
        a, b = graph._obs["ij"][k]
        sub._obs.append(ij=(local[int(a)], local[int(b)]), mu=graph._obs["mu"][k],
                        W=graph._obs["W"][k], off=graph._obs["off"][k], dim=graph._obs["dim"][k])
    for p, h in zip(graph.priors, hit_p, strict=True):
        if h:
            sub.priors.append(LinearPrior(np.array([local[int(n)] for n in p.nodes]), p.x0, p.A,
                                          p.b))
    sub._version += 1
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

    # Remove the factors and nodes from the graph.
    graph._between.keep(~hit_b)
    graph._obs.keep(~hit_o)
    graph.priors = [p for p, h_ in zip(graph.priors, hit_p, strict=True) if not h_]
    graph._nodes["active"][drop] = False
    graph._version += 1
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
    graph.priors.append(LinearPrior(keep_nodes, graph.poses[keep_nodes].copy(), a_mat, b_vec))
    graph._version += 1


def se2_exp(xi: np.ndarray) -> np.ndarray:
    """SE(2) exponential of tangent vectors ``(..., 3)`` as poses ``(x, y, heading)``."""
    xi = np.asarray(xi, dtype=float)
    th = xi[..., 2]
    small = np.abs(th) < 1e-6
    ths = np.where(small, 1.0, th)
    sa = np.where(small, 1.0 - th**2 / 6.0, np.sin(ths) / ths)
    cb = np.where(small, th / 2.0, (1.0 - np.cos(ths)) / ths)
    x = sa * xi[..., 0] - cb * xi[..., 1]
    y = cb * xi[..., 0] + sa * xi[..., 1]
    return np.stack([x, y, wrap_angle(th)], axis=-1)


def compose(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``pose (+) delta``: the pose at ``delta`` expressed in the frame of ``pose``."""
    pose, delta = np.asarray(pose, dtype=float), np.asarray(delta, dtype=float)
    c, s = np.cos(pose[..., 2]), np.sin(pose[..., 2])
    return np.stack(
        [
            pose[..., 0] + c * delta[..., 0] - s * delta[..., 1],
            pose[..., 1] + s * delta[..., 0] + c * delta[..., 1],
            wrap_angle(pose[..., 2] + delta[..., 2]),
        ],
        axis=-1,
    )


def between(pose_a: np.ndarray, pose_b: np.ndarray) -> np.ndarray:
    """``pose_a^-1 (+) pose_b``: pose ``b`` in the frame of pose ``a``."""
    pose_a, pose_b = np.asarray(pose_a, dtype=float), np.asarray(pose_b, dtype=float)
    c, s = np.cos(pose_a[..., 2]), np.sin(pose_a[..., 2])
    dx, dy = pose_b[..., 0] - pose_a[..., 0], pose_b[..., 1] - pose_a[..., 1]
    return np.stack(
        [c * dx + s * dy, -s * dx + c * dy, wrap_angle(pose_b[..., 2] - pose_a[..., 2])], axis=-1
    )


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

