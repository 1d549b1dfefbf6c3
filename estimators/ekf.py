"""Extended Kalman filter over the planar poses of a team of robots (Madhavan et al.).

One file: prediction, gated updates and their lock-out recovery share PoseEKF's arrays.

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

A validation gate alone can lock a filter out: once the estimate has drifted
(wheels spinning against a wall, a long outage), every later fix fails the
gate and the filter never hears the truth again while its covariance stays
small. :class:`GateMonitor` counts consecutive rejections per robot and sensor;
past ``recover_after`` of them the filter concludes that it, not the sensor, is
wrong, and widens the robot's covariance in the subspace the sensor observes
until the reading is an ordinary one (:func:`observed_inflation`) before fusing
it. A
single outlier (a multipath fix) is still rejected. Relative detections get
the same treatment through track confirmation (see :meth:`PoseEKF.update_relative`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from estimators._ekf_kernels import propagate_rest
from estimators.gating import GateMonitor, chi2_threshold, observed_inflation
from estimators.geometry import wrap_angle, wrap_angle_in_place
from estimators.relative_model import best_ci_weight, disjoint_rounds, stacked_relative_measurement
from estimators.relative_model import relative_measurement as relative_measurement

__all__ = ["Belief", "GateMonitor", "PoseEKF", "chi2_threshold", "relative_measurement"]


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
        recover_after: consecutive gate rejections of one robot's sensor (or of one
            observer-target pair's detections, when consistent with each other)
            after which the filter widens the covariance and fuses the reading
            (:class:`GateMonitor`); ``None`` never recovers.
        confirm_distance: a relative detection that would move a robot's position
            estimate by more than this (m) is fused only once a second detection
            of the same pair, at most ``confirm_window`` predictions later (env
            steps), agrees with it (one the gate rejects needs ``recover_after``
            agreeing ones); ``None``: no confirmation.
        confirm_window: see ``confirm_distance``.
    """

    def __init__(
        self,
        mean: np.ndarray,
        cov: np.ndarray,
        gate_prob: float = 0.99,
        recover_after: int | None = 3,
        confirm_distance: float | None = 1.0,
        confirm_window: int = 10,
    ) -> None:
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
        self.monitor = GateMonitor(len(mean), recover_after)
        if confirm_distance is not None and not (
            np.isfinite(confirm_distance) and confirm_distance >= 0
        ):
            raise ValueError(f"confirm_distance must be >= 0 or None, got {confirm_distance!r}")
        if isinstance(confirm_window, bool) or not isinstance(confirm_window, int | np.integer) \
                or confirm_window < 1:
            raise ValueError(f"confirm_window must be a positive int, got {confirm_window!r}")
        self.confirm_distance = confirm_distance
        self.confirm_window = int(confirm_window)
        # (lower, higher robot index) -> the pair's track of detections waiting for
        # confirmation: (update_relative call number, prediction count, position offset of
        # the higher one as seen by the lower one (+ relative orientation), its covariance,
        # number of agreeing detections in the track).
        self._pending: dict[tuple[int, int], tuple] = {}
        self._relative_calls = 0
        self._ticks = 0  # predictions so far: the clock of the confirmation window

    @property
    def n(self) -> int:
        """Number of robots."""
        return len(self.mean)

    def belief(self, i: int) -> Belief:
        """Robot ``i``'s current belief (copies)."""
        return Belief(self.mean[i].copy(), self.cov[i].copy())

    def inflate(self, idx: np.ndarray, q: np.ndarray) -> None:
        """Add process noise ``q`` (``(k, 3, 3)`` or one ``(3, 3)``, symmetric PSD) to the
        covariances of robots ``idx``: motion the odometry could not measure."""
        idx = np.asarray(idx, dtype=int)
        q = np.asarray(q, dtype=float)
        _check_finite("q", q)
        self.cov[idx] += _symmetrize(q)

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
        self._ticks += 1
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
        self.predict_sequence_stacked(v, w, dt, _variances(var_v, var_w, v.shape))

    def predict_sequence_stacked(
        self, v: np.ndarray, w: np.ndarray, dt: float, q: np.ndarray
    ) -> None:
        """:meth:`predict_sequence` (its one implementation) for callers that hold the
        variances stacked: float ``v``, ``w`` ``(T, n)`` and ``q`` ``(2, T, n)``, ``var_v``
        then ``var_w`` (read only). Equals ``T`` sequential :meth:`predict` calls of all
        robots up to rounding; the env's odometry step calls it once per step."""
        self._ticks += 1
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
        channel: str | None = None,
    ) -> np.ndarray:
        """Gated EKF update of robots ``idx`` (distinct) with measurements ``z``.

        Args:
            idx: robot indices, shape ``(k,)``, no repeats.
            z: measurements ``(k, m)``; ``h``: predicted measurements ``(k, m)``.
            jac: measurement Jacobians ``(k, m, 3)``; ``r``: noise ``(k, m, m)``.
            angle_dims: measurement components that are angles (wrapped).
            gate_prob: chi-square gate probability (default ``self.gate_prob``);
                ``1.0`` disables gating.
            channel: the sensor's name for the lock-out recovery (consecutive
                rejections are counted per robot and channel); ``None``: no recovery.

        Returns:
            Boolean mask ``(k,)`` of accepted measurements (recoveries included).
        """
        idx, sel, z = self._checked(idx, z)
        if not len(idx):
            return np.zeros(0, dtype=bool)
        nu = z - h
        for d in angle_dims:
            nu[:, d] = wrap_angle(nu[:, d])
        jac, r = np.asarray(jac, dtype=float), np.asarray(r, dtype=float)
        return self._update(idx, sel, nu, jac, r, gate_prob, channel, tuple(angle_dims))

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
        channel: str | None = None,
        angles: tuple[int, ...] = (),
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
        if channel is not None and self.monitor.pending(channel, n_ok < len(ok)):
            recover = self.monitor.record(channel, idx, ok, nu, s, angles)
            recover &= np.isfinite(d2)  # (a singular S gives no scale to widen by)
            if n_ok < len(ok) and recover.any():
                # Locked out: widen the covariance in the subspace the sensor sees until the
                # reading is an ordinary one (normalized innovation = its dof), then fuse it.
                rows = np.nonzero(recover)[0]
                sel_rows = idx[rows]
                jr = jac if jac.ndim == 2 else jac[rows]
                self.cov[sel_rows] += observed_inflation(
                    self.cov[sel_rows], jr, d2[rows] / nu.shape[1]
                )
                ok = ok | recover
                n_ok = np.count_nonzero(ok)
                p = self.cov[sel]
                ph_t = p @ jac.mT
                s = jac @ ph_t
                s += r
                s_inv = 1.0 / s if s.shape[-1] == 1 else np.linalg.inv(s)
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
        """DGPS update: ``z = (x, y)``, ``H = [[1,0,0],[0,1,0]]``, noise ``r (k, 2, 2)``.

        Gated, with the lock-out recovery of channel ``"position"``."""
        idx, sel, z = self._checked(idx, z)
        if not len(idx):
            return np.zeros(0, dtype=bool)
        nu = z - self.mean[sel, :2]
        r = np.asarray(r, dtype=float)
        return self._update(idx, sel, nu, _H_POSITION, r, gate_prob, "position")

    def update_heading(
        self, idx: np.ndarray, z: np.ndarray, var: np.ndarray, gate_prob: float | None = None
    ) -> np.ndarray:
        """Compass update: ``z = phi``, ``H = [0, 0, 1]``, noise variance ``var (k,)``.

        Gated, with the lock-out recovery of channel ``"heading"``."""
        idx, sel, z = self._checked(idx, z)
        if not len(idx):
            return np.zeros(0, dtype=bool)
        nu = wrap_angle(z.reshape(-1, 1) - self.mean[sel, 2:3])
        r = np.asarray(var, dtype=float).reshape(-1, 1, 1)
        return self._update(idx, sel, nu, _H_HEADING, r, gate_prob, "heading", (0,))

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
            gate_prob: chi-square gate probability. The gate uses the innovation
                covariance of the two marginals as they are (not the CI-inflated one).
                Detections that fail it, or would move a robot by more than
                ``confirm_distance``, wait for confirmation (:meth:`_confirm`); a
                confirmed detection that fails the gate triggers a recovery.
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
        self._relative_calls += 1
        priority = np.argsort(-self.cov[idx_b].trace(axis1=1, axis2=2), kind="stable")
        limit = max_rounds if max_rounds is None or max_rounds >= 0 else None
        for rows in disjoint_rounds(idx_a[priority], idx_b[priority], self.n, limit)[:max_rounds]:
            rows = priority[rows]
            accepted[rows] = self._joint_update(
                idx_a[rows], idx_b[rows], z[rows], r[rows], model, dims, gate_prob, fusion
            )
        return accepted

    def _joint_update(
        self, ia, ib, z, r, model, dims, gate_prob, fusion, confirm: bool = True
    ) -> np.ndarray:
        """One round of :meth:`update_relative` (each robot in at most one pair)."""
        k = len(ia)
        iab = np.concatenate((ia, ib))
        xa, xb = self.mean[iab].reshape(2, k, 3)
        z_full, r_full = z, r
        h, jac = stacked_relative_measurement(xa, xb, model)  # jac (k, 3, 6): [H_a, H_b]
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
        nu = z - h
        nu[:, angles] = wrap_angle(nu[:, angles])
        # Gate on the innovation covariance of the marginals as they are. The CI inflation
        # below bounds the unknown correlation for the fusion, but it also widens S (by up
        # to 1 / w), which would let detections through that the beliefs call implausible.
        ha, hb = jac[:, :, :3], jac[:, :, 3:]
        s0 = ha @ pa @ ha.mT + hb @ pb @ hb.mT
        s0 += r
        d2 = np.einsum("ki,kij,kj->k", nu, np.linalg.inv(s0), nu)
        ok = self._gate(d2, nu.shape[1], gate_prob)
        if fusion == "ci":
            w = best_ci_weight(pab, jac, r)[:, None, None]
            pa_w, pb_w = pa / w, pb / (1 - w)
        else:
            pa_w, pb_w = pa, pb
        p = np.zeros((k, 6, 6))
        p[:, :3, :3] = pa_w
        p[:, 3:, 3:] = pb_w
        ph_t = p @ jac.mT
        s = jac @ ph_t
        s += r
        gain = ph_t @ np.linalg.inv(s)
        dx = np.einsum("kij,kj->ki", gain, nu)
        i_kh = _EYE6 - gain @ jac
        p_new = i_kh @ p @ i_kh.mT
        p_new += gain @ r @ gain.mT
        p_new += p_new.mT  # symmetrize in place (numpy buffers the overlapping transpose)
        p_new *= 0.5
        sides = ((slice(0, 3), ia, pa), (slice(3, 6), ib, pb))
        if fusion == "ci":  # keep a robot's prior where the update would not shrink it
            moves = [p_new[:, sl, sl].trace(axis1=1, axis2=2) < prior.trace(axis1=1, axis2=2)
                     for sl, _, prior in sides]
        else:
            moves = [np.ones(k, dtype=bool)] * 2
        recover = np.zeros(k, dtype=bool)
        if confirm and self.confirm_distance is not None and {0, 1} <= set(dims):
            shift = np.maximum(*(
                np.hypot(dx[:, sl][:, 0], dx[:, sl][:, 1]) * mv
                for (sl, _, _), mv in zip(sides, moves, strict=True)
            ))
            ok, recover = self._confirm(
                ia, ib, z_full, r_full, model, ok, shift > self.confirm_distance, 2 in dims
            )
        for (sl, rob, _), mv in zip(sides, moves, strict=True):
            take = ok & mv
            if not take.any():
                continue
            mean = self.mean[rob[take]]
            mean += dx[take, sl]
            wrap_angle_in_place(mean[:, 2])
            self.mean[rob[take]] = mean
            self.cov[rob[take]] = p_new[take, sl, sl]
        if recover.any():
            ok[recover] = self._recover_relative(
                ia[recover], ib[recover], z_full[recover], r_full[recover], model, dims,
                fusion, ok[recover],
            )
        return ok

    def _relative_offsets(
        self, ia: np.ndarray, ib: np.ndarray, z: np.ndarray, r: np.ndarray, model: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where detections ``z (k, 3)`` put the targets minus where they are believed to be,
        ``(k, 2)``, with the covariance of the measurement noise in it ``(k, 2, 2)``. (The
        estimates' own errors are left out: they change little between two detections,
        so they cancel when two offsets are compared.)"""
        xa, xb = self.mean[ia], self.mean[ib]
        if model == "cartesian":
            return xa[:, :2] - z[:, :2] - xb[:, :2], r[:, :2, :2].copy()
        ang = xa[:, 2] + z[:, 1]
        c, sn = np.cos(ang), np.sin(ang)
        rng = z[:, 0]
        offset = xa[:, :2] + rng[:, None] * np.stack([c, sn], axis=1) - xb[:, :2]
        jac = np.empty((len(ia), 2, 2))  # d(point) / d(range, bearing)
        jac[:, 0, 0], jac[:, 0, 1] = c, -rng * sn
        jac[:, 1, 0], jac[:, 1, 1] = sn, rng * c
        return offset, jac @ r[:, :2, :2] @ jac.mT

    def _confirm(
        self, ia, ib, z, r, model, ok: np.ndarray, big: np.ndarray, with_orientation: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """Track confirmation of relative detections.

        A detection that fails the gate, or would move a robot by more than
        ``confirm_distance``, joins the pair's track (either robot observing):
        it agrees with the track's last detection, from an earlier call and at
        most ``confirm_window`` predictions old, when both put the target at the
        same offset from its estimate and (``with_orientation``) see the same
        relative orientation (chi-square test at the gate probability, with the
        two readings' noise plus :data:`_CONFIRM_SLACK` for the motion in
        between); otherwise it starts a new track. A detection is fused once its
        track holds 2 agreeing detections, or ``recover_after`` (default 3) when
        the gate rejected it, as it then overrules the belief. A false positive
        names a random place, so a track of them is rare. Returns the mask of
        detections accepted as they are and the mask of confirmed ones (for
        :meth:`_recover_relative`).
        """
        need = np.nonzero(big | ~ok)[0]
        accepted = ok & ~big
        recover = np.zeros(len(ok), dtype=bool)
        if not len(need):
            return accepted, recover
        call, tick = self._relative_calls, self._ticks
        offset, cov = self._relative_offsets(ia[need], ib[need], z[need], r[need], model)
        if with_orientation:
            vec = np.concatenate([offset, z[need, 2:3]], axis=1)
            full = np.zeros((len(need), 3, 3))
            full[:, :2, :2] = cov
            full[:, 2, 2] = r[need, 2, 2]
            cov, slack = full, _CONFIRM_SLACK_3
        else:
            vec, slack = offset, _CONFIRM_SLACK_2
        dof = vec.shape[1]
        threshold = chi2_threshold(self.gate_prob, dof) if self.gate_prob < 1.0 else np.inf
        lock_out = self.monitor.recover_after or 2
        for row, v, c in zip(need.tolist(), vec, cov, strict=True):
            # One track per pair, whoever observes: seen from the target, the offset and
            # the relative orientation flip.
            a, b = int(ia[row]), int(ib[row])
            key = (a, b) if a < b else (b, a)
            if a > b:
                v = -v
            count = 1
            prev = self._pending.pop(key, None)
            if prev is not None and prev[0] < call and tick - prev[1] <= self.confirm_window \
                    and len(prev[2]) == dof:
                diff = v - prev[2]
                if dof == 3:
                    diff[2] = (diff[2] + np.pi) % (2 * np.pi) - np.pi
                if diff @ np.linalg.solve(c + prev[3] + slack, diff) <= threshold:
                    count = prev[4] + 1
            if count >= (2 if ok[row] else lock_out):
                recover[row] = True
            else:
                self._pending[key] = (call, tick, v, c, count)
        return accepted, recover

    def _recover_relative(self, ia, ib, z, r, model, dims, fusion, passed) -> np.ndarray:
        """Fuse confirmed detections. The more uncertain robot of each pair first moves to
        where the detections put it (by the offset ``o`` they agree on), so that the
        update is linearized near the truth rather than metres away; where the gate had
        rejected the detection (the robot was locked out) its position covariance also
        widens by ``o o^T``. Then the detection is fused ungated."""
        offset, _ = self._relative_offsets(ia, ib, z, r, model)
        trace_a = self.cov[ia, 0, 0] + self.cov[ia, 1, 1]
        trace_b = self.cov[ib, 0, 0] + self.cov[ib, 1, 1]
        target_lost = trace_b >= trace_a
        lost = np.where(target_lost, ib, ia)
        self.mean[lost, :2] += np.where(target_lost[:, None], offset, -offset)
        widen = ~passed
        self.cov[lost[widen], :2, :2] += offset[widen, :, None] * offset[widen, None, :]
        self.monitor.recoveries += int(np.count_nonzero(widen))
        return self._joint_update(ia, ib, z, r, model, dims, 1.0, fusion, confirm=False)


# Std (m) of how much the offset between a robot's estimate and where a detection puts it
# may change between two confirming detections (odometry drift over the window).
_CONFIRM_SLACK = 0.3
# ... and of the relative orientation two detections measure (rad): both robots turn.
_CONFIRM_SLACK_HEADING = 0.1
_CONFIRM_SLACK_2 = np.eye(2) * _CONFIRM_SLACK**2
_CONFIRM_SLACK_3 = np.diag([_CONFIRM_SLACK**2] * 2 + [_CONFIRM_SLACK_HEADING**2])
for _slack in (_CONFIRM_SLACK_2, _CONFIRM_SLACK_3):
    _slack.flags.writeable = False


def _propagate(
    mean: np.ndarray,
    p: np.ndarray,
    v: np.ndarray,
    w: np.ndarray,
    dt: float,
    q: np.ndarray,
) -> None:
    """``T`` unicycle EKF predictions of ``k`` robots in place; ``v``, ``w`` ``(T, k)``.

    ``q`` ``(2, T, k)`` holds ``var_v`` and ``var_w`` (read only).

    The headings along the way follow from a cumulative sum, and the Jacobians
    ``Fx_t = I + a_t e02 + b_t e12`` commute, so their product and each noise
    term's propagation through the later Jacobians are sums.

    The noise entering at substep ``t`` is ``G_t diag(qv_t, qw_t) G_t^T`` with
    ``G_t = [[c_t, 0], [s_t, 0], [0, 1]]`` (``qv = dt^2 var_v``, ``qw = dt^2
    var_w``); the later Jacobians ``I + a'_t e02 + b'_t e12`` (``a'_t``, ``b'_t``:
    sums over ``j > t``) turn ``G_t`` into ``L_t = [[c_t, a'_t], [s_t, b'_t], [0,
    1]]``, so the total is ``sum_t qv_t l0 l0^T + qw_t l1 l1^T`` over the columns
    ``l0 = (c, s, 0)``, ``l1 = (a', b', 1)`` of the ``L_t``: one contraction over
    the ``2 T`` columns. After the headings (numpy's cumulative sum, cosine and
    sine), one compiled pass per robot does the rest
    (:func:`estimators._ekf_kernels.propagate_rest`, bit-identical to that numpy
    contraction).
    """
    n_sub, k = v.shape
    # phi[t]: heading before substep t (t < T); phi[T]: heading after the last one.
    phi = np.empty((n_sub + 1, k))
    phi[0] = mean[:, 2]
    np.multiply(w, dt, out=phi[1:])
    np.add.accumulate(phi, axis=0, out=phi)
    heading = phi[:-1]
    # The Jacobians, the mean, F P F^T and the noise sum in one compiled pass (the same
    # operations as the numpy formulation above, in the same order).
    propagate_rest(mean, p, v, dt, q, phi[-1], np.cos(heading), np.sin(heading))


def _variances(var_v: np.ndarray | float, var_w: np.ndarray | float, shape: tuple) -> np.ndarray:
    """``var_v`` and ``var_w`` (each broadcast to ``shape``) stacked in a fresh ``(2, *shape)``."""
    q = np.empty((2, *shape))
    q[0] = var_v
    q[1] = var_w
    return q


