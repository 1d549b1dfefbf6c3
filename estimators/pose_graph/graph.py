"""The pose graph: nodes (poses of robots at sampled times) and Gaussian factors.

Factors are stored column-wise (one growable array per field) so that residuals,
Jacobians and the normal equations are evaluated for a whole factor group at once.
See :mod:`estimators.pose_graph` for the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from estimators.geometry import wrap_angle
from estimators.pose_graph.se2 import (
    DEFAULT_MIN_RANGE,
    between_residual,
    check_pose,
    observation_residual,
    sqrt_information,
)

COMPONENTS = "rbo"
"""Letters naming the components of a robot observation: range, bearing, orientation."""

DENSE_MAX_VARIABLES = 450
"""Problems with at most this many variables use dense Cholesky, larger ones sparse LU..."""

DENSE_FILL_MAX_VARIABLES = 3000
"""...unless ``H`` is more than 5 % full and has at most this many variables."""


def check_observation(components: str, measurement) -> np.ndarray:
    """``measurement`` as a float array after checking it against ``components`` (a
    non-empty subset of :data:`COMPONENTS`, one finite number each); ``ValueError`` naming
    the bad value otherwise."""
    if not components or any(ch not in COMPONENTS for ch in components) or len(
        set(components)
    ) != len(components):
        raise ValueError(f"components must be a non-empty subset of 'rbo', got {components!r}")
    k = len(components)
    meas = np.asarray(measurement, dtype=float).reshape(-1)
    if meas.shape != (k,) or not np.all(np.isfinite(meas)):
        raise ValueError(f"measurement must be {k} finite numbers, got {measurement!r}")
    return meas


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
class FactorSelection:
    """A subset of the factors of a :class:`PoseGraph`: one mask per factor kind."""

    between: np.ndarray
    """Boolean mask over the motion factors."""
    observation: np.ndarray
    """Boolean mask over the robot-observation factors."""
    priors: list[bool]
    """One flag per entry of :attr:`PoseGraph.priors`."""




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
        pose = check_pose(pose, "pose")
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

    def check_nodes(self, nodes: np.ndarray) -> np.ndarray:
        """``nodes`` as an int array; raises ``ValueError`` naming any that is not active."""
        return np.asarray([self._check_node(n) for n in np.atleast_1d(nodes)], dtype=int)

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
        delta = check_pose(delta, "delta")
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
        meas = check_observation(components, measurement)
        k = len(components)
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
            off[0] = check_pose(offset_a, "offset_a")
        if offset_b is not None:
            off[1] = check_pose(offset_b, "offset_b")
        self._obs.append(ij=(a, b), mu=mu, W=w, off=off, dim=k)
        self._version += 1

    def add_prior(
        self, nodes: np.ndarray, x0: np.ndarray, A: np.ndarray, b: np.ndarray | None = None
    ) -> None:
        """Linear prior ``0.5 ||A (x_S (-) x0) + b||^2`` over ``nodes`` (``A`` is ``(q, 3|S|)``)."""
        nodes = self.check_nodes(nodes)
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
        self.add_prior([node], check_pose(pose, "pose"), np.diag(1.0 / std))

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

    def factors_touching(self, nodes: np.ndarray) -> FactorSelection:
        """The factors with at least one node in ``nodes`` (a boolean mask over all nodes)."""
        return FactorSelection(
            between=nodes[self._between["ij"]].any(axis=1),
            observation=nodes[self._obs["ij"]].any(axis=1),
            priors=[bool(nodes[p.nodes].any()) for p in self.priors],
        )

    def selection_nodes(self, selection: FactorSelection) -> list[np.ndarray]:
        """Node ids of the selected factors: motion, then observation, then each prior's."""
        return [
            self._between["ij"][selection.between].ravel(),
            self._obs["ij"][selection.observation].ravel(),
        ] + [p.nodes for p, hit in zip(self.priors, selection.priors, strict=True) if hit]

    def subgraph(self, nodes: np.ndarray, selection: FactorSelection) -> PoseGraph:
        """A new graph of ``nodes`` (renumbered ``0..len(nodes)-1`` in that order, with their
        estimates and flags) and the selected factors, which may only touch ``nodes``."""
        sub = PoseGraph(self.min_range)
        local = {int(n): k for k, n in enumerate(nodes)}
        for n in nodes:
            sub.add_node(self.poses[n], int(self.node_robot[n]), float(self.node_time[n]),
                         bool(self.fixed[n]))
        bt, ob = self._between, self._obs
        for k in np.flatnonzero(selection.between):
            i, j = bt["ij"][k]
            sub._between.append(ij=(local[int(i)], local[int(j)]), mu=bt["mu"][k], W=bt["W"][k])
        for k in np.flatnonzero(selection.observation):
            a, b = ob["ij"][k]
            sub._obs.append(ij=(local[int(a)], local[int(b)]), mu=ob["mu"][k], W=ob["W"][k],
                            off=ob["off"][k], dim=ob["dim"][k])
        for p, hit in zip(self.priors, selection.priors, strict=True):
            if hit:
                sub.priors.append(
                    LinearPrior(np.array([local[int(n)] for n in p.nodes]), p.x0, p.A, p.b)
                )
        sub._version += 1
        return sub

    def remove(self, selection: FactorSelection, nodes: np.ndarray) -> None:
        """Delete the selected factors and make ``nodes`` inactive (they keep their estimates)."""
        self._between.keep(~selection.between)
        self._obs.keep(~selection.observation)
        self.priors = [p for p, hit in zip(self.priors, selection.priors, strict=True) if not hit]
        self._nodes["active"][nodes] = False
        self._version += 1

    def append_prior(self, prior: LinearPrior) -> None:
        """Add an already built linear prior as is (no checks, no copies; see :meth:`add_prior`)."""
        self.priors.append(prior)
        self._version += 1

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

    def diagonal_slots(self) -> np.ndarray:
        """Positions of the diagonal entries in the data of the sparse ``H`` of
        :meth:`normal_equations` (its pattern always includes the diagonal)."""
        return self._structure("sparse")["h_diag"]

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
