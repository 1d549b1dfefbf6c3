"""Extended Kalman filter over the planar poses of a team of robots (Madhavan et al.).

:class:`PoseEKF` keeps one independent ``(x, y, heading)`` state and 3x3
covariance per robot and works on all robots at once with numpy batch
operations, so a team of 50 robots costs about as much Python as a team of 1.

* :meth:`PoseEKF.predict` is Eq. 1/2 of the outdoor paper: unicycle motion
  driven by odometry ``u = (V, w)`` with additive Gaussian noise.
* :meth:`PoseEKF.update_position` (DGPS), :meth:`PoseEKF.update_heading`
  (compass) and the generic :meth:`PoseEKF.update` apply a chi-square
  validation gate before the update.
* :meth:`PoseEKF.update_relative` is the cooperative update of Eq. 3: the
  relative pose of robot ``b`` measured by robot ``a`` updates the stacked
  state ``[x_a; x_b]`` in one joint EKF step. The paper keeps the robots'
  filters separate (prediction stays local), so the cross-covariance the joint
  step creates is not stored: each robot keeps its updated marginal. Eq. 3's
  measurement is the Cartesian difference ``[x_a - x_b, y_a - y_b, phi_a -
  phi_b]`` (linear, ``H = [I, -I]``); robot detectors, lasers and cameras
  measure range, bearing and orientation instead, so ``model="rbo"`` uses that
  nonlinear form with its Jacobian (``model="cartesian"`` is the paper's).

Covariance updates use the Joseph form followed by symmetrization, which keeps
them symmetric positive definite in floating point.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators.geometry import wrap_angle, wrap_angle_in_place

_CHI2_CACHE: dict[tuple[float, int], float] = {}


def chi2_threshold(prob: float, dof: int) -> float:
    """Chi-square gate threshold: the ``prob`` quantile with ``dof`` degrees of freedom."""
    if not 0.0 < prob < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {prob!r}")
    key = (float(prob), int(dof))
    if key not in _CHI2_CACHE:
        _CHI2_CACHE[key] = float(chi2.ppf(prob, dof))
    return _CHI2_CACHE[key]


@dataclass(frozen=True)
class Belief:
    """A Gaussian pose belief: ``mean`` (3,) and ``cov`` (3, 3)."""

    mean: np.ndarray
    cov: np.ndarray


_EYE3 = np.eye(3)
_EYE3.flags.writeable = False
# Measurement Jacobians of the DGPS (x, y) and the compass (phi), shared by all robots.
_H_POSITION = np.eye(3)[:2]
_H_POSITION.flags.writeable = False
_H_HEADING = np.eye(3)[2:]
_H_HEADING.flags.writeable = False
_EYE6 = np.eye(6)
_EYE6.flags.writeable = False


@functools.lru_cache(maxsize=16)
def _arange(n: int) -> np.ndarray:
    """``np.arange(n)``, made once per ``n`` and read-only (it is shared)."""
    out = np.arange(n)
    out.flags.writeable = False
    return out


def _check_finite(name: str, value: np.ndarray) -> None:
    if not np.isfinite(value).all():
        raise ValueError(f"{name} contains NaN or inf: {value!r}")


def _symmetrize(p: np.ndarray) -> np.ndarray:
    return 0.5 * (p + np.swapaxes(p, -1, -2))


class PoseEKF:
    """Independent pose EKFs for ``n`` robots, updated in batches.

    Args:
        mean: initial poses, shape ``(n, 3)``.
        cov: initial covariances, shape ``(n, 3, 3)`` (or ``(3, 3)`` for all).
        gate_prob: default chi-square gate probability (e.g. 0.99).
    """

    def __init__(self, mean: np.ndarray, cov: np.ndarray, gate_prob: float = 0.99) -> None:
        mean = np.array(mean, dtype=float).reshape(-1, 3)
        cov = np.array(cov, dtype=float)
        if cov.shape == (3, 3):
            cov = np.repeat(cov[None], len(mean), axis=0)
        if cov.shape != (len(mean), 3, 3):
            raise ValueError(f"cov must have shape ({len(mean)}, 3, 3), got {cov.shape}")
        _check_finite("mean", mean)
        _check_finite("cov", cov)
        chi2_threshold(gate_prob, 1)
        self.mean = mean
        self.mean[:, 2] = wrap_angle(self.mean[:, 2])
        self.cov = _symmetrize(cov)
        self.gate_prob = gate_prob

    @property
    def n(self) -> int:
        """Number of robots."""
        return len(self.mean)

    def belief(self, i: int) -> Belief:
        """Robot ``i``'s current belief (copies)."""
        return Belief(self.mean[i].copy(), self.cov[i].copy())

    # ------------------------------------------------------------------ predict
    def predict(
        self,
        v: np.ndarray,
        w: np.ndarray,
        dt: float,
        var_v: np.ndarray | float,
        var_w: np.ndarray | float,
        idx: np.ndarray | None = None,
    ) -> None:
        """Propagate with odometry ``(V, w)`` over ``dt`` (Eq. 1 and 2).

        ``v``, ``w``, ``var_v``, ``var_w`` are per robot (or scalars); ``idx``
        selects which robots to predict (default all).
        """
        sel = slice(None) if idx is None else np.asarray(idx)
        k = len(self.mean[sel])
        as_row = lambda x: np.broadcast_to(np.asarray(x, dtype=float), (k,))[None]  # noqa: E731
        mean, cov = self.mean[sel], self.cov[sel]
        _propagate(mean, cov, as_row(v), as_row(w), dt, _variances(var_v, var_w, (1, k)))
        self.mean[sel], self.cov[sel] = mean, cov

    def predict_sequence(
        self,
        v: np.ndarray,
        w: np.ndarray,
        dt: float,
        var_v: np.ndarray | float,
        var_w: np.ndarray | float,
    ) -> None:
        """Apply ``T`` consecutive :meth:`predict` steps at once (all robots).

        ``v``, ``w`` (and the variances) have shape ``(T, n)``. The result equals
        ``T`` sequential calls up to rounding (see :func:`_propagate`).
        """
        v = np.asarray(v, dtype=float)
        w = np.asarray(w, dtype=float)
        self._predict_sequence(v, w, dt, _variances(var_v, var_w, v.shape))

    def _predict_sequence(self, v: np.ndarray, w: np.ndarray, dt: float, q: np.ndarray) -> None:
        """:meth:`predict_sequence` (its one implementation) of float ``v``, ``w`` ``(T, n)``
        with the variances stacked in a fresh C-ordered ``q`` ``(2, T, n)``: ``var_v`` then
        ``var_w`` (overwritten)."""
        _propagate(self.mean, self.cov, v, w, dt, q)

    # ------------------------------------------------------------------ updates
    def update(
        self,
        idx: np.ndarray,
        z: np.ndarray,
        h: np.ndarray,
        jac: np.ndarray,
        r: np.ndarray,
        angle_dims: tuple[int, ...] = (),
        gate_prob: float | None = None,
    ) -> np.ndarray:
        """Gated EKF update of robots ``idx`` (distinct) with measurements ``z``.

        Args:
            idx: robot indices, shape ``(k,)``, no repeats.
            z: measurements ``(k, m)``; ``h``: predicted measurements ``(k, m)``.
            jac: measurement Jacobians ``(k, m, 3)``; ``r``: noise ``(k, m, m)``.
            angle_dims: measurement components that are angles (wrapped).
            gate_prob: chi-square gate probability (default ``self.gate_prob``);
                ``1.0`` disables gating.

        Returns:
            Boolean mask ``(k,)`` of accepted measurements.
        """
        idx, sel, z = self._checked(idx, z)
        if not len(idx):
            return np.zeros(0, dtype=bool)
        nu = z - h
        for d in angle_dims:
            nu[:, d] = wrap_angle(nu[:, d])
        jac, r = np.asarray(jac, dtype=float), np.asarray(r, dtype=float)
        return self._update(idx, sel, nu, jac, r, gate_prob)

    def _checked(
        self, idx: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | slice, np.ndarray]:
        """``idx`` as ints, the rows it selects (``slice(None)`` when it is every robot in
        order: views instead of copies) and ``z`` as floats, checked finite."""
        idx = np.asarray(idx, dtype=int)
        if not len(idx):
            return idx, idx, np.zeros(0)
        _check_finite("z", z)
        n = len(self.mean)
        sel = slice(None) if len(idx) == n and (idx == _arange(n)).all() else idx
        return idx, sel, np.asarray(z, dtype=float)

    def _update(
        self,
        idx: np.ndarray,
        sel: np.ndarray | slice,
        nu: np.ndarray,
        jac: np.ndarray,
        r: np.ndarray,
        gate_prob: float | None,
    ) -> np.ndarray:
        """:meth:`update` of robots ``idx`` (``sel``: ``idx`` or ``slice(None)`` for all of
        them in order) from innovations ``nu (k, m)``; ``jac`` is ``(k, m, 3)`` or one
        ``(m, 3)`` shared by all. Returns the accepted mask."""
        p = self.cov[sel]
        ph_t = p @ jac.mT
        s = jac @ ph_t
        s += r
        # 1x1: the reciprocal is what LAPACK computes, without its per-call overhead.
        s_inv = 1.0 / s if s.shape[-1] == 1 else np.linalg.inv(s)
        d2 = np.einsum("ki,kij,kj->k", nu, s_inv, nu)
        ok = self._gate(d2, nu.shape[1], gate_prob)
        n_ok = np.count_nonzero(ok)
        if not n_ok:
            return ok
        if n_ok < len(ok):  # keep the accepted rows (all accepted: use them as they are)
            ph_t, s_inv, nu, sel, p, r = ph_t[ok], s_inv[ok], nu[ok], idx[ok], p[ok], r[ok]
            if jac.ndim == 3:
                jac = jac[ok]
        gain = ph_t @ s_inv
        dx = (gain @ nu[:, :, None])[:, :, 0]
        mean = self.mean if isinstance(sel, slice) else self.mean[sel]
        mean += dx
        wrap_angle_in_place(mean[:, 2])
        i_kh = _EYE3 - gain @ jac
        p_new = i_kh @ p @ i_kh.mT
        p_new += gain @ r @ gain.mT
        # Symmetrize in place: (P + P^T) / 2 (numpy buffers the overlapping transpose).
        p_new += p_new.mT
        p_new *= 0.5
        if not isinstance(sel, slice):
            self.mean[sel] = mean
        self.cov[sel] = p_new
        return ok

    def _gate(self, d2: np.ndarray, dof: int, gate_prob: float | None) -> np.ndarray:
        prob = self.gate_prob if gate_prob is None else gate_prob
        if prob >= 1.0:
            return np.isfinite(d2)
        return d2 <= chi2_threshold(prob, dof)

    def update_position(
        self, idx: np.ndarray, z: np.ndarray, r: np.ndarray, gate_prob: float | None = None
    ) -> np.ndarray:
        """DGPS update: ``z = (x, y)``, ``H = [[1,0,0],[0,1,0]]``, noise ``r (k, 2, 2)``."""
        idx, sel, z = self._checked(idx, z)
        if not len(idx):
            return np.zeros(0, dtype=bool)
        nu = z - self.mean[sel, :2]
        return self._update(idx, sel, nu, _H_POSITION, np.asarray(r, dtype=float), gate_prob)

    def update_heading(
        self, idx: np.ndarray, z: np.ndarray, var: np.ndarray, gate_prob: float | None = None
    ) -> np.ndarray:
        """Compass update: ``z = phi``, ``H = [0, 0, 1]``, noise variance ``var (k,)``."""
        idx, sel, z = self._checked(idx, z)
        if not len(idx):
            return np.zeros(0, dtype=bool)
        nu = wrap_angle(z.reshape(-1, 1) - self.mean[sel, 2:3])
        r = np.asarray(var, dtype=float).reshape(-1, 1, 1)
        return self._update(idx, sel, nu, _H_HEADING, r, gate_prob)

    def update_relative(
        self,
        idx_a: np.ndarray,
        idx_b: np.ndarray,
        z: np.ndarray,
        r: np.ndarray,
        model: str = "rbo",
        dims: tuple[int, ...] = (0, 1, 2),
        gate_prob: float | None = None,
        fusion: str = "ci",
        max_rounds: int | None = None,
    ) -> np.ndarray:
        """Cooperative update (Eq. 3) from relative measurements of ``b`` by ``a``.

        Args:
            idx_a, idx_b: observer and observed robot indices ``(k,)``.
            z: measurements ``(k, 3)``: ``(range, bearing, orientation)`` of ``b``
                seen from ``a`` for ``model="rbo"``, or ``(x_a - x_b, y_a - y_b,
                phi_a - phi_b)`` for ``model="cartesian"`` (the paper's form).
            r: measurement noise ``(k, 3, 3)``.
            dims: which of the three components to use (e.g. ``(0, 1)`` for
                range and bearing only).
            gate_prob: chi-square gate probability.
            fusion: ``"naive"`` stacks the two marginals as if independent (the
                paper's form; repeated meetings then double count and the
                covariances become overconfident); ``"ci"`` (default) inflates
                them by covariance-intersection weights ``P_a / w``,
                ``P_b / (1 - w)`` with ``w = tr P_b / (tr P_a + tr P_b)``, an
                upper bound of the joint covariance whatever the unknown
                correlation, and keeps a robot's prior where the update would
                not shrink it.
            max_rounds: pairs are processed in rounds in which every robot
                appears at most once (most uncertain targets first); at most
                this many rounds run (``None`` = all), bounding the cost per step.

        Returns:
            Boolean mask ``(k,)``: the measurement passed the gate and was fused.
        """
        if model not in ("rbo", "cartesian"):
            raise ValueError(f"unknown relative measurement model {model!r}")
        if fusion not in ("ci", "naive"):
            raise ValueError(f"fusion must be 'ci' or 'naive', got {fusion!r}")
        idx_a = np.asarray(idx_a, dtype=int)
        idx_b = np.asarray(idx_b, dtype=int)
        z = np.asarray(z, dtype=float).reshape(-1, 3)
        r = np.asarray(r, dtype=float).reshape(-1, 3, 3)
        if (idx_a == idx_b).any():
            raise ValueError("a robot cannot observe itself in a relative update")
        accepted = np.zeros(len(idx_a), dtype=bool)
        priority = np.argsort(-self.cov[idx_b].trace(axis1=1, axis2=2), kind="stable")
        limit = max_rounds if max_rounds is None or max_rounds >= 0 else None
        for rows in _rounds(idx_a[priority], idx_b[priority], self.n, limit)[:max_rounds]:
            rows = priority[rows]
            accepted[rows] = self._joint_update(
                idx_a[rows], idx_b[rows], z[rows], r[rows], model, dims, gate_prob, fusion
            )
        return accepted

    def _joint_update(self, ia, ib, z, r, model, dims, gate_prob, fusion) -> np.ndarray:
        """One round of :meth:`update_relative` (each robot in at most one pair)."""
        k = len(ia)
        iab = np.concatenate((ia, ib))
        xa, xb = self.mean[iab].reshape(2, k, 3)
        h, jac = _relative_measurement(xa, xb, model)  # jac (k, 3, 6): [H_a, H_b]
        first_angle = 2 if model == "cartesian" else 1
        if tuple(dims) == (0, 1, 2):
            angles: list[int] | slice = slice(first_angle, None)
        else:
            dims = list(dims)
            h, jac, z = h[:, dims], jac[:, dims], z[:, dims]
            r = r[:, dims][:, :, dims]
            angles = [j for j, d in enumerate(dims) if d >= first_angle]
        pab = self.cov[iab].reshape(2, k, 3, 3)
        pa, pb = pab
        if fusion == "ci":
            w = _best_ci_weight(pab, jac, r)[:, None, None]
            pa_w, pb_w = pa / w, pb / (1 - w)
        else:
            pa_w, pb_w = pa, pb
        p = np.zeros((k, 6, 6))
        p[:, :3, :3] = pa_w
        p[:, 3:, 3:] = pb_w
        nu = z - h
        nu[:, angles] = wrap_angle(nu[:, angles])
        ph_t = p @ jac.mT
        s = jac @ ph_t
        s += r
        s_inv = np.linalg.inv(s)
        d2 = np.einsum("ki,kij,kj->k", nu, s_inv, nu)
        ok = self._gate(d2, nu.shape[1], gate_prob)
        n_ok = np.count_nonzero(ok)
        if not n_ok:
            return ok
        if n_ok < len(ok):
            ph_t, s_inv, nu, jac, p, r = ph_t[ok], s_inv[ok], nu[ok], jac[ok], p[ok], r[ok]
            ia, ib, pa, pb = ia[ok], ib[ok], pa[ok], pb[ok]
        gain = ph_t @ s_inv
        dx = np.einsum("kij,kj->ki", gain, nu)
        i_kh = _EYE6 - gain @ jac
        p_new = i_kh @ p @ i_kh.mT
        p_new += gain @ r @ gain.mT
        p_new += p_new.mT  # symmetrize in place (numpy buffers the overlapping transpose)
        p_new *= 0.5
        for sl, rob, prior in ((slice(0, 3), ia, pa), (slice(3, 6), ib, pb)):
            post = p_new[:, sl, sl]
            step = dx[:, sl]
            if fusion == "ci":  # keep the prior where the update would not shrink it
                keep = post.trace(axis1=1, axis2=2) < prior.trace(axis1=1, axis2=2)
                if np.count_nonzero(keep) < len(keep):
                    rob, post, step = rob[keep], post[keep], step[keep]
            mean = self.mean[rob]
            mean += step
            wrap_angle_in_place(mean[:, 2])
            self.mean[rob] = mean
            self.cov[rob] = post
        return ok


def _propagate(
    mean: np.ndarray,
    p: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    dt: float,
    q: np.ndarray,
) -> None:
    """``T`` unicycle EKF predictions of ``k`` robots in place; ``v``, ``w`` ``(T, k)``.

    ``q`` ``(2, T, k)``, C-ordered, holds ``var_v`` and ``var_w``; it is scaled in
    place (to ``dt^2`` times them).

    The headings along the way follow from a cumulative sum, and the Jacobians
    ``Fx_t = I + a_t e02 + b_t e12`` commute, so their product and each noise
    term's propagation through the later Jacobians are sums.

    The noise entering at substep ``t`` is ``G_t diag(qv_t, qw_t) G_t^T`` with
    ``G_t = [[c_t, 0], [s_t, 0], [0, 1]]`` (``qv = dt^2 var_v``, ``qw = dt^2
    var_w``); the later Jacobians ``I + a'_t e02 + b'_t e12`` (``a'_t``, ``b'_t``:
    sums over ``j > t``) turn ``G_t`` into ``L_t = [[c_t, a'_t], [s_t, b'_t], [0,
    1]]``, so the total is ``sum_t qv_t l0 l0^T + qw_t l1 l1^T`` over the columns
    ``l0 = (c, s, 0)``, ``l1 = (a', b', 1)`` of the ``L_t``: one contraction over
    the ``2 T`` columns. Arrays keep the robots on the last axis, so each numpy
    call is one long inner loop whatever the team size.
    """
    n_sub, k = v.shape
    # phi[t]: heading before substep t (t < T); phi[T]: heading after the last one.
    phi = np.empty((n_sub + 1, k))
    phi[0] = mean[:, 2]
    np.multiply(w, dt, out=phi[1:])
    np.add.accumulate(phi, axis=0, out=phi)
    # cols[i, m, t]: entry i of column m of L_t (for each robot).
    cols = np.empty((3, 2, n_sub, k))
    cols[2] = _ZERO_ONE
    heading = phi[:-1]
    np.cos(heading, out=cols[0, 0])
    np.sin(heading, out=cols[1, 0])
    # ba = (b, a) = (dv cos(phi), -dv sin(phi)) with dv = dt v: the Jacobian entries.
    ba = cols[:2, 0] * (v * _signed(dt))
    ba_cum = np.add.accumulate(ba, axis=1)
    ba_tot = ba_cum[:, -1]  # (B, A): sums over all substeps
    # Later Jacobians applied to the noise entering at substep t: a'_t, b'_t.
    np.subtract(ba_tot[:, None], ba_cum, out=cols[1::-1, 1])
    xy = mean[:, :2]
    xy += (ba_tot * _PLUS_MINUS).T  # x += B, y -= A
    last = phi[-1]
    wrap_angle_in_place(last)
    mean[:, 2] = last
    # F P F^T with F = I + A e02 + B e12: rows 0 and 1 gain A, B times row 2, then columns.
    ab_tot = ba_tot[::-1].T  # (k, 2): A, B
    top = p[:, :2, :]
    top += ab_tot[:, :, None] * p[:, 2:3, :]
    left = p[:, :, :2]
    left += p[:, :, 2:3] * ab_tot[:, None, :]
    q *= dt * dt  # qv, qw: the weights of l0, l1
    # (l_i l_j) q is symmetric in i, j, so the covariance stays exactly symmetric.
    p += np.einsum("imtk,jmtk,mtk->kij", cols, cols, q)


_ZERO_ONE = np.array([0.0, 1.0])[:, None, None]  # third entry of l0, l1
_PLUS_MINUS = np.array([1.0, -1.0])[:, None]


def _variances(var_v: np.ndarray | float, var_w: np.ndarray | float, shape: tuple) -> np.ndarray:
    """``var_v`` and ``var_w`` (each broadcast to ``shape``) stacked in a fresh ``(2, *shape)``."""
    q = np.empty((2, *shape))
    q[0] = var_v
    q[1] = var_w
    return q


@functools.lru_cache(maxsize=8)
def _signed(dt: float) -> np.ndarray:
    """``(dt, -dt)`` shaped ``(2, 1, 1)``, read-only (made once per ``dt``)."""
    out = np.array([dt, -dt])[:, None, None]
    out.flags.writeable = False
    return out


def relative_measurement(
    xa: np.ndarray, xb: np.ndarray, model: str = "rbo"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted relative measurement of ``xb`` from ``xa`` and its Jacobians.

    Returns ``(h, H_a, H_b)`` with shapes ``(k, 3)``, ``(k, 3, 3)``, ``(k, 3, 3)``.
    For ``model="rbo"`` the range is floored at 1 mm so the bearing Jacobian
    stays finite when two estimates coincide.
    """
    if model not in ("rbo", "cartesian"):
        raise ValueError(f"unknown relative measurement model {model!r}")
    xa = np.asarray(xa, dtype=float).reshape(-1, 3)
    xb = np.asarray(xb, dtype=float).reshape(-1, 3)
    if xa.shape != xb.shape:
        raise ValueError(f"xa and xb must have the same shape, got {xa.shape} and {xb.shape}")
    h, jac = _relative_measurement(xa, xb, model)
    return h, jac[:, :, :3].copy(), jac[:, :, 3:].copy()


# Constant entries of the stacked Jacobians [H_a, H_b] (3, 6) of the two models.
_JAC_CONST = {
    "cartesian": np.hstack([np.eye(3), -np.eye(3)]),
    "rbo": np.array([[0.0] * 6, [0, 0, -1, 0, 0, 0], [0, 0, -1, 0, 0, 1]], dtype=float),
}
for _jac in _JAC_CONST.values():
    _jac.flags.writeable = False
_FLIP = np.array([1.0, -1.0])


def _relative_measurement(
    xa: np.ndarray, xb: np.ndarray, model: str
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`relative_measurement` of ``(k, 3)`` float poses with the Jacobians side by
    side: ``(h (k, 3), [H_a, H_b] (k, 3, 6))``."""
    k = len(xa)
    jac = np.empty((k, 3, 6))
    jac[:] = _JAC_CONST[model]
    if model == "cartesian":
        h = xa - xb
        wrap_angle_in_place(h[:, 2])
        return h, jac
    d = xb[:, :2] - xa[:, :2]  # (dx, dy)
    sq = d * d
    q = sq[:, 0] + sq[:, 1]
    np.maximum(q, 1e-6, out=q)
    h = np.empty((k, 3))
    rng = np.sqrt(q, out=h[:, 0])
    np.arctan2(d[:, 1], d[:, 0], out=h[:, 1])
    h[:, 2] = xb[:, 2]
    h[:, 1:] -= xa[:, 2:3]
    wrap_angle_in_place(h[:, 1:])
    # Range row: (-dx, -dy, 0, dx, dy, 0) / range; bearing row: (dy, -dx, -1, -dy, dx, 0) / q.
    ur = d / rng[:, None]
    jac[:, 0, 3:5] = ur
    np.negative(ur, out=jac[:, 0, :2])
    bearing = jac[:, 1, :2]
    np.multiply(d[:, ::-1] / q[:, None], _FLIP, out=bearing)
    np.negative(bearing, out=jac[:, 1, 3:5])
    return h, jac


_CI_WEIGHTS = np.linspace(0.05, 0.95, 10)
_CI_WEIGHTS.flags.writeable = False
# The weights of robot a (w) and robot b (1 - w), shaped to divide (2, 1, k, m, m) blocks.
_CI_SCALES = np.stack([_CI_WEIGHTS, 1 - _CI_WEIGHTS])[:, :, None, None, None]
_CI_SCALES.flags.writeable = False


def _best_ci_weight(pab: np.ndarray, jac: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Covariance-intersection weight per pair (grid search over ``_CI_WEIGHTS``).

    ``pab (2, k, 3, 3)``: the priors ``P_a``, ``P_b``; ``jac (k, m, 6)``: ``[H_a, H_b]``;
    ``r (k, m, m)``.

    Minimizes the summed trace of the two robots' covariances after the update,
    counting a robot whose inflated posterior would exceed its prior at its prior
    (the update leaves such a robot unchanged).

    With ``P_a / w``, ``P_b / (1 - w)`` on the diagonal, ``U_a = P_a H_a^T``,
    ``U_b = P_b H_b^T`` and ``S(w) = H_a U_a / w + H_b U_b / (1 - w) + R``, robot
    ``a``'s posterior trace is ``tr P_a / w - tr(S(w)^-1 U_a^T U_a) / w^2`` (and
    likewise for ``b`` with ``1 - w``): only ``m x m`` matrices per weight.
    """
    k, m = jac.shape[:2]
    jab = jac.reshape(k, m, 2, 3).transpose(2, 0, 1, 3)  # (2, k, m, 3): H_a, H_b
    u = pab @ jab.mT  # (2, k, 3, m)
    s = (jab @ u)[:, None] / _CI_SCALES  # (2, weights, k, m, m)
    s = s[0] + s[1]
    s += r
    gram = u.mT @ u  # (2, k, m, m), symmetric
    if m == 3 and k >= _COFACTOR_MIN_PAIRS:
        # tr(S^-1 G) = sum(C * G) / det S with C the cofactors of S (G symmetric): a
        # few whole-array operations instead of LAPACK's per-matrix cost.
        cof, det = _cofactors3(s)
        reduction = np.einsum("wkij,gkij->gwk", cof, gram) / det
    else:
        reduction = np.einsum("wkij,gkij->gwk", np.linalg.inv(s), gram)
    prior = pab.trace(axis1=2, axis2=3)[:, None]  # (2, 1, k)
    scale = _CI_SCALES[..., 0, 0]  # (2, weights, 1): w and 1 - w
    post = prior / scale - reduction / (scale * scale)
    np.minimum(post, prior, out=post)
    return _CI_WEIGHTS[np.argmin(post[0] + post[1], axis=0)]


# From this many pairs on, _best_ci_weight's 10 k 3x3 systems go through cofactors
# (cheaper than np.linalg.inv from about 40 matrices on).
_COFACTOR_MIN_PAIRS = 4
_NEXT = np.array([1, 2, 0])
_AFTER_NEXT = np.array([2, 0, 1])


def _cofactors3(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cofactor matrices and determinants of a stack of 3x3 matrices ``s (..., 3, 3)``.

    Row ``i`` of the cofactors is ``row_{i+1} x row_{i+2}`` (indices mod 3), so
    ``S^-1 = C^T / det S`` with ``det S = row_0 . C_0``.
    """
    a, b = s[..., _NEXT, :], s[..., _AFTER_NEXT, :]
    cof = a[..., _NEXT] * b[..., _AFTER_NEXT]
    cof -= a[..., _AFTER_NEXT] * b[..., _NEXT]
    det = np.einsum("...j,...j->...", s[..., 0, :], cof[..., 0, :])
    return cof, det


def _rounds(
    idx_a: np.ndarray, idx_b: np.ndarray, n: int, max_rounds: int | None = None
) -> list[np.ndarray]:
    """Split pairs into rounds in which every robot index appears at most once (greedy, in
    order); only the first ``max_rounds`` rounds are formed (``None``: all)."""
    a_list, b_list = idx_a.tolist(), idx_b.tolist()
    remaining = list(range(len(a_list)))
    rounds = []
    while remaining and (max_rounds is None or len(rounds) < max_rounds):
        used = [False] * n
        take = []
        rest = []
        for row in remaining:
            a, b = a_list[row], b_list[row]
            if used[a] or used[b]:
                rest.append(row)
            else:
                used[a] = used[b] = True
                take.append(row)
        rounds.append(np.asarray(take, dtype=int))
        remaining = rest
    return rounds
