"""Centralized full-covariance EKF over the poses of a robot team, for logged data.

The state stacks every robot's ``(x, y, heading)``; the covariance is the full
``3n x 3n`` matrix, so cross-covariances created by robot-to-robot
measurements are kept (the centralized form of Eq. 3 of Madhavan et al.,
with range-bearing instead of a Cartesian relative pose).

* Prediction is the unicycle model of Eq. 1/2 driven by logged velocity
  commands. :class:`OdometryTrack` integrates one robot's command log once, so
  the motion and its process-noise covariance between *any* two times cost
  O(1) (prefix sums), which lets the filter predict lazily: a robot is only
  propagated when one of its measurements arrives or its belief is read.
  Predictions of different robots touch disjoint rows/columns of the
  covariance, so the lazy order gives the same result as stepping all robots.
* :meth:`TeamEKF.update_landmark`: range-bearing to a known landmark.
* :meth:`TeamEKF.update_robot`: range-bearing from robot ``i`` to robot ``j``,
  one joint update of both poses and everything correlated with them.
* Every update passes a chi-square validation gate (``scipy.stats.chi2``);
  the covariance update is the Joseph form followed by symmetrization. A robot
  is taken to be lost (locked out by the gate), not the landmarks wrong, only
  when its recent landmark readings all agree on one well-determined pose,
  odometry included, that explains the readings of several landmarks metres
  apart better than the belief does and that the belief rules out, or, whatever
  the gate says, agree on a pose far from the belief even without any one
  landmark's readings; its belief is then replaced by that pose
  (:class:`~estimators.relocalization.Relocalizer`).

Independent per-robot EKFs are the same class with ``cooperative=False``:
robot-to-robot updates are then skipped and the covariance stays block
diagonal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimators.ekf import Belief
from estimators.gating import chi2_threshold
from estimators.geometry import wrap_angle
from estimators.relocalization import Relocalizer

__all__ = ["MotionNoise", "OdometryTrack", "TeamEKF"]


@dataclass(frozen=True)
class MotionNoise:
    """Continuous-time noise on the velocity commands ``(v, w)``.

    The spectral densities grow with the command magnitude:
    ``q_v = v0 + v1 * |v|`` [m^2/s^2 * s] and ``q_w = w0 + w1 * |w|``
    [rad^2/s^2 * s]; the variance of the integrated velocity error over a
    time ``T`` at constant command is ``q * T``.
    """

    v0: float
    v1: float
    w0: float
    w1: float

    def __post_init__(self) -> None:
        for name in ("v0", "v1", "w0", "w1"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"MotionNoise.{name} must be finite and >= 0, got {value!r}")


# Column layout of the prefix-sum table of OdometryTrack.
_TH, _X, _Y, _CC, _CS, _SS, _S0, _SX, _SY, _SXX, _SXY, _SYY = range(12)


class OdometryTrack:
    """One robot's velocity-command log, integrated for O(1) motion queries.

    Record ``k`` holds the command ``(v_k, w_k)`` from ``t_k + delay`` until the
    next record's time (the last one holds forever); before the first record
    the robot does not move. Commands are multiplied by ``v_scale`` and
    ``w_scale`` (calibrated from ground truth). Within a record the robot
    follows the exact circular arc of constant ``(v, w)`` (Eq. 1 of the
    outdoor paper is its first-order Euler form).

    Args:
        times: record times, shape ``(N,)``, non-decreasing.
        v: forward velocity commands [m/s], shape ``(N,)``.
        w: angular velocity commands [rad/s], shape ``(N,)``.
        noise: the process noise model.
        delay: command-to-motion latency [s] added to every time.
        v_scale, w_scale: multiplicative calibration of the commands.
    """

    def __init__(
        self,
        times: np.ndarray,
        v: np.ndarray,
        w: np.ndarray,
        noise: MotionNoise,
        delay: float = 0.0,
        v_scale: float = 1.0,
        w_scale: float = 1.0,
    ) -> None:
        t = np.asarray(times, dtype=float) + float(delay)
        v = np.asarray(v, dtype=float) * float(v_scale)
        w = np.asarray(w, dtype=float) * float(w_scale)
        if t.ndim != 1 or t.size == 0 or v.shape != t.shape or w.shape != t.shape:
            raise ValueError(
                f"times, v, w must be equal-length non-empty 1-D arrays, got shapes "
                f"{np.shape(times)}, {np.shape(v)}, {np.shape(w)}"
            )
        for name, arr in (("times", t), ("v", v), ("w", w)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"odometry {name} contains NaN or inf")
        if np.any(np.diff(t) < 0):
            k = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
            raise ValueError(f"odometry times go backwards at index {k}: {t[k]!r} < {t[k - 1]!r}")
        dt = np.diff(t)
        n = t.size
        qv = noise.v0 + noise.v1 * np.abs(v)
        qw = noise.w0 + noise.w1 * np.abs(w)
        theta = np.concatenate([[0.0], np.cumsum(w[:-1] * dt)])
        half = 0.5 * w[:-1] * dt
        mid = theta[:-1] + half
        chord = v[:-1] * dt * np.sinc(half / np.pi)  # exact arc: v dt sin(h)/h
        x = np.concatenate([[0.0], np.cumsum(chord * np.cos(mid))])
        y = np.concatenate([[0.0], np.cumsum(chord * np.sin(mid))])
        c, s = np.cos(theta), np.sin(theta)
        rate = np.zeros((n, 12))  # integrand of each cumulative column within a record
        rate[:, _TH] = w
        rate[:, _CC] = qv * c * c
        rate[:, _CS] = qv * c * s
        rate[:, _SS] = qv * s * s
        rate[:, _S0] = qw
        rate[:, _SX] = qw * x
        rate[:, _SY] = qw * y
        rate[:, _SXX] = qw * x * x
        rate[:, _SXY] = qw * x * y
        rate[:, _SYY] = qw * y * y
        cum = np.zeros((n, 12))
        cum[1:] = np.cumsum(rate[:-1] * dt[:, None], axis=0)
        cum[:, _X] = x
        cum[:, _Y] = y
        self.times = t
        self._v = v
        self._w = w
        self._cum = cum
        self._rate = rate

    def state(self, t: float) -> np.ndarray:
        """The cumulative table row (odometry-frame pose and noise integrals) at time ``t``."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        if k < 0:
            return np.zeros(12)
        tau = t - self.times[k]
        row = self._cum[k] + tau * self._rate[k]
        th0 = self._cum[k, _TH]
        half = 0.5 * float(self._w[k]) * tau
        sinc = 1.0 - half * half / 6.0 if abs(half) < 1e-4 else math.sin(half) / half
        step = float(self._v[k]) * tau * sinc
        mid = float(th0) + half
        row[_X] = self._cum[k, _X] + step * math.cos(mid)
        row[_Y] = self._cum[k, _Y] + step * math.sin(mid)
        return row

    def turn_rate(self, t: float) -> float:
        """The (calibrated) turn rate command in force at time ``t`` (0 before the log)."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return float(self._w[k]) if k >= 0 else 0.0

    @staticmethod
    def motion(ca: np.ndarray, cb: np.ndarray, heading_a: float) -> tuple[np.ndarray, np.ndarray]:
        """World-frame pose increment and process covariance between two table rows.

        ``ca``/``cb`` come from :meth:`state` at the start and end times and
        ``heading_a`` is the (estimated) heading at the start. Returns
        ``(delta (3,), Q (3, 3))``: the new pose is ``pose_a + delta`` and the
        Jacobian of the motion w.r.t. ``pose_a`` is
        ``[[1, 0, -delta_y], [0, 1, delta_x], [0, 0, 1]]``.
        """
        d = (cb - ca).tolist()
        xb, yb = float(cb[_X]), float(cb[_Y])
        s0 = d[_S0]
        sx, sy = d[_SX], d[_SY]
        qxx = yb * yb * s0 - 2.0 * yb * sy + d[_SYY] + d[_CC]
        qyy = xb * xb * s0 - 2.0 * xb * sx + d[_SXX] + d[_SS]
        qxy = -(xb * yb * s0 - yb * sx - xb * sy + d[_SXY]) + d[_CS]
        qxt = -(yb * s0 - sy)
        qyt = xb * s0 - sx
        rot = float(heading_a - ca[_TH])
        c, s = math.cos(rot), math.sin(rot)
        dx = c * d[_X] - s * d[_Y]
        dy = s * d[_X] + c * d[_Y]
        m = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        q_odo = np.array([[qxx, qxy, qxt], [qxy, qyy, qyt], [qxt, qyt, s0]])
        q = m @ q_odo @ m.T
        return np.array([dx, dy, d[_TH]]), 0.5 * (q + q.T)


class TeamEKF:
    """Centralized EKF over ``n`` robot poses with a full ``3n x 3n`` covariance.

    Args:
        tracks: one :class:`OdometryTrack` per robot (index order = state order).
        mean: initial poses ``(n, 3)``.
        cov: initial covariance, ``(3, 3)`` per robot, ``(n, 3, 3)`` or ``(3n, 3n)``.
        t0: time of the initial poses.
        gate_prob: chi-square validation gate probability (2 degrees of freedom).
        cooperative: apply robot-to-robot updates (``False`` = independent EKFs).
        sensor_offset: ``(n, 2)`` position of each robot's range-bearing sensor
            in its body frame (default: at the pose's origin). Targets (landmarks,
            other robots' poses) are points.
        recover_after: landmark readings of a robot (of at least two landmarks 1 m
            apart, agreeing on one pose the belief rules out) that prove it lost and
            re-localize it (:class:`~estimators.relocalization.Relocalizer`;
            ``None``: never).
    """

    def __init__(
        self,
        tracks: list[OdometryTrack],
        mean: np.ndarray,
        cov: np.ndarray,
        t0: float,
        gate_prob: float = 0.99,
        cooperative: bool = True,
        sensor_offset: np.ndarray | None = None,
        recover_after: int | None = 3,
    ) -> None:
        n = len(tracks)
        mean = np.array(mean, dtype=float)
        if mean.shape != (n, 3):
            raise ValueError(f"mean must have shape ({n}, 3), got {mean.shape}")
        cov = np.array(cov, dtype=float)
        p = np.zeros((3 * n, 3 * n))
        if cov.shape == (3, 3):
            for i in range(n):
                p[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = cov
        elif cov.shape == (n, 3, 3):
            for i in range(n):
                p[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] = cov[i]
        elif cov.shape == (3 * n, 3 * n):
            p = cov.copy()
        else:
            raise ValueError(f"cov must have shape (3, 3), ({n}, 3, 3) or ({3 * n}, {3 * n})")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(p))):
            raise ValueError("initial mean/cov contain NaN or inf")
        self.tracks = list(tracks)
        self.x = mean.reshape(-1).copy()
        self.x[2::3] = wrap_angle(self.x[2::3])
        self.P = 0.5 * (p + p.T)
        self.time = np.full(n, float(t0))
        self._table = [tr.state(float(t0)) for tr in self.tracks]
        self.gate = chi2_threshold(gate_prob, 2)
        self.cooperative = bool(cooperative)
        off = np.zeros((n, 2)) if sensor_offset is None else np.array(sensor_offset, dtype=float)
        if off.shape != (n, 2) or not np.all(np.isfinite(off)):
            raise ValueError(f"sensor_offset must be a finite ({n}, 2) array, got {off!r}")
        self.sensor_offset = off
        self.accepted = np.zeros(n, dtype=int)
        self.rejected = np.zeros(n, dtype=int)
        self.relocalizer = Relocalizer(n, OdometryTrack.motion, min_readings=recover_after)

    @property
    def n(self) -> int:
        """Number of robots."""
        return len(self.tracks)

    def predict_to(self, i: int, t: float) -> None:
        """Propagate robot ``i`` to time ``t`` (no-op if it is already there or later)."""
        if t <= self.time[i]:
            return
        cb = self.tracks[i].state(t)
        a = 3 * i
        delta, q = OdometryTrack.motion(self._table[i], cb, self.x[a + 2])
        f = np.array([[1.0, 0.0, -delta[1]], [0.0, 1.0, delta[0]], [0.0, 0.0, 1.0]])
        self.x[a : a + 3] += delta
        self.x[a + 2] = wrap_angle(self.x[a + 2])
        rows = self.P[a : a + 3, :]
        rows = f @ rows
        self.P[a : a + 3, :] = rows
        self.P[:, a : a + 3] = self.P[:, a : a + 3] @ f.T
        self.P[a : a + 3, a : a + 3] += q
        self.time[i] = t
        self._table[i] = cb

    def belief(self, i: int) -> Belief:
        """Robot ``i``'s current marginal belief (at its own last propagated time)."""
        a = 3 * i
        return Belief(self.x[a : a + 3].copy(), self.P[a : a + 3, a : a + 3].copy())

    def _apply(
        self, idx: np.ndarray, h: np.ndarray, nu: np.ndarray, r: np.ndarray, who: int
    ) -> bool:
        """Gated Joseph-form update with the Jacobian ``h`` over state indices ``idx``
        (a reading of robot ``who``).

        With ``B = H P`` (nonzero columns of ``H`` only) and ``S = H P H^T + R``,
        the Joseph form ``(I - K H) P (I - K H)^T + K R K^T`` expands to
        ``P - K B - B^T K^T + K S K^T``: rank-2 terms, no ``3n x 3n`` products.
        """
        self._last_d2 = np.inf  # the gate statistic of this reading, for the relocalizer
        b = h @ self.P[idx, :]  # (2, 3n)
        s = b[:, idx] @ h.T + r
        det = s[0, 0] * s[1, 1] - s[0, 1] * s[1, 0]
        if not (np.isfinite(det) and det > 0.0):
            self.rejected[who] += 1
            return False
        s_inv = np.array([[s[1, 1], -s[0, 1]], [-s[1, 0], s[0, 0]]]) / det
        d2 = float(nu @ s_inv @ nu)
        passed = bool(np.isfinite(d2) and d2 <= self.gate)
        self._last_d2 = d2 if np.isfinite(d2) else np.inf
        if not passed:
            self.rejected[who] += 1
            return False
        k = b.T @ s_inv  # (3n, 2) = P H^T S^-1
        self.x += k @ nu
        self.x[2::3] = wrap_angle(self.x[2::3])
        kb = k @ b
        p = self.P - kb - kb.T + k @ s @ k.T
        self.P = 0.5 * (p + p.T)
        self.accepted[who] += 1
        return True

    def _range_bearing(
        self, i: int, target: np.ndarray, z: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Innovation and Jacobians of a range-bearing reading from robot ``i`` to a point.

        Returns ``(nu, H_i (2, 3), H_target (2, 2))`` or ``None`` when the
        predicted range is degenerate.
        """
        a = 3 * i
        px, py, phi = self.x[a], self.x[a + 1], self.x[a + 2]
        c, s = np.cos(phi), np.sin(phi)
        ox, oy = self.sensor_offset[i]
        sx = px + c * ox - s * oy
        sy = py + s * ox + c * oy
        dsx, dsy = -s * ox - c * oy, c * ox - s * oy  # d(sensor)/d(phi)
        dx, dy = target[0] - sx, target[1] - sy
        q = dx * dx + dy * dy
        if q < 1e-12:
            return None
        rng = np.sqrt(q)
        nu = np.array([z[0] - rng, wrap_angle(z[1] - (np.arctan2(dy, dx) - phi))])
        h_t = np.array([[dx / rng, dy / rng], [-dy / q, dx / q]])
        h_i = np.array(
            [
                [-dx / rng, -dy / rng, -(dx * dsx + dy * dsy) / rng],
                [dy / q, -dx / q, (dy * dsx - dx * dsy) / q - 1.0],
            ]
        )
        return nu, h_i, h_t

    def update_landmark(
        self, i: int, landmark: np.ndarray, z: np.ndarray, r: np.ndarray, t: float | None = None
    ) -> bool:
        """Range-bearing ``z`` from robot ``i`` to a landmark at ``landmark`` (x, y).

        ``r`` is the 2x2 measurement covariance. If ``t`` is given robot ``i``
        is first propagated to it. Returns whether the gate accepted it.
        """
        if t is not None:
            self.predict_to(i, t)
        res = self._range_bearing(i, np.asarray(landmark, dtype=float), z)
        if res is None:
            self.rejected[i] += 1
            return False
        nu, h_i, _ = res
        passed = self._apply(np.arange(3 * i, 3 * i + 3), h_i, nu, r, i)
        reloc = self.relocalizer
        if not reloc.enabled:
            return passed
        a = 3 * i
        mark = np.asarray(landmark, dtype=float)
        reloc.add(i, self.time[i], self._table[i], self.tracks[i].turn_rate(self.time[i]),
                  tuple(mark.tolist()), mark, z, r, self._last_d2, not passed)
        fix = reloc.propose(i, self.sensor_offset[i], self.x[a : a + 3],
                            self.P[a : a + 3, a : a + 3])
        if fix is None:
            return passed
        self._relocate(i, *fix)
        reloc.clear(i)
        reloc.recoveries += 1
        if not passed:
            self.rejected[i] -= 1
            self.accepted[i] += 1
        return True

    def _relocate(self, i: int, pose: np.ndarray, cov: np.ndarray) -> None:
        """Replace robot ``i``'s belief by ``pose`` with covariance ``cov``, uncorrelated
        with the others' (a re-localization from its own readings)."""
        a = 3 * i
        self.x[a : a + 3] = pose
        self.x[a + 2] = wrap_angle(self.x[a + 2])
        self.P[a : a + 3, :] = 0.0
        self.P[:, a : a + 3] = 0.0
        self.P[a : a + 3, a : a + 3] = 0.5 * (cov + cov.T)

    def update_robot(
        self, i: int, j: int, z: np.ndarray, r: np.ndarray, t: float | None = None
    ) -> bool:
        """Range-bearing ``z`` of robot ``j`` measured by robot ``i``: joint update.

        Skipped (returns ``False``, not counted as rejected) when the filter
        is not cooperative.
        """
        if not self.cooperative:
            return False
        if i == j:
            raise ValueError(f"a robot cannot measure itself (i = j = {i})")
        if t is not None:
            self.predict_to(i, t)
            self.predict_to(j, t)
        b = 3 * j
        res = self._range_bearing(i, self.x[b : b + 2], z)
        if res is None:
            self.rejected[i] += 1
            return False
        nu, h_i, h_t = res
        h = np.hstack([h_i, h_t])
        idx = np.r_[3 * i : 3 * i + 3, b : b + 2]
        return self._apply(idx, h, nu, r, i)
