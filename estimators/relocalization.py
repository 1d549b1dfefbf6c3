"""Lock-out recovery of a landmark filter: re-localize a robot whose belief is wrong.

A validation gate can lock a filter out: once its estimate has drifted away
with a small covariance, every later landmark reading fails the gate (or, with
a generous gate, passes it narrowly while the filter creeps back over a
minute). But a run of rejected readings is not by itself evidence that the
*filter* is wrong: one biased or misidentified landmark, or a burst of bearings
taken while the robot turns, also fails the gate again and again, and readings
of one landmark agree with each other however wrong they are.
:class:`Relocalizer` keeps each robot's landmark readings of the last
``window_s`` seconds, accepted or not (none taken while turning faster than
``max_turn_rate``), and looks into them when the gate statistics of several
landmarks' readings run high: their mean, per landmark, above the 0.9 quantile
of the chi-square distribution of one reading. That is a bar an accurate filter
clears only by chance, whether its noise model is generous or tight: a bar at
the median of the sum's distribution is crossed half the time by a consistent
filter, and a model fitted on a quieter dataset than the one replayed leaves
every landmark near it, so that the tests below alone stand between an
accurate filter and a wrong re-localization. It overrules the belief only
when

* one pose explains *all* of them, the accepted ones too, with the odometry
  between them (:func:`fit_pose`: chi-square test of the residuals, the
  odometry's noise over each reading's age added to their covariance), so an
  accurate filter, whose accepted readings contradict the outliers, is left
  alone;
* that pose is well determined (``max_std``: readings of one cluster of
  landmarks seen from afar leave it loose);
* it explains the readings of at least ``min_landmarks`` landmarks (each read
  twice or more), some two of them ``min_baseline`` or more apart, better than
  the belief does (chi-square gain per landmark): a biased landmark is one
  landmark, a single outlier reading is no landmark's verdict, and
  landmarks a few decimetres apart constrain a pose like one;
* and the belief rules it out (chi-square test of the difference, with both
  covariances).

A belief can also settle on a wrong pose whose readings pass the gate: one
cluster of landmarks places a robot only up to a circle around it, and a
generous noise model lets a pose metres off pass. So the readings are also
searched for a *consensus* every ``check_every_s``, whatever their gate
statistics (:meth:`Relocalizer._consensus`): the best of several local optima
of the fit, which must come from landmarks of ``min_places`` places (groups of
landmarks ``min_baseline`` apart), explain every reading, be determined within
``consensus_std``, lie ``min_jump`` or more from the belief, beat every other
optimum that far away by the 0.999 bound of 3 dof (two poses the readings
cannot tell apart: no verdict), explain the readings ``min_ratio`` times better
than the belief (a ratio of chi-squares, which a model too confident or too
generous passes alike), and still beat the belief by that bound when the
readings of any one landmark are left out (a biased or misidentified landmark
is one landmark).

The robot's belief is then replaced by the fitted pose and its covariance (no
correlation with the others: it rests on the landmarks and the robot's own
odometry only); the readings it rests on are not fused a second time.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np

from estimators.gating import chi2_threshold

__all__ = ["Relocalizer", "fit_candidates", "fit_pose", "residuals"]

# Headings tried as starting points of the fit (the lost robot's heading may be anything).
_HEADINGS = np.linspace(-np.pi, np.pi, 180, endpoint=False)
_STARTS = 3  # the best few of them are refined
_CONSENSUS_STARTS = 6  # ... and more of them when several optima must be compared


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _rot(a: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(k, 2, 2)`` of angles ``a (k,)``."""
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _predict(
    pose: np.ndarray, rel: np.ndarray, marks: np.ndarray, offset: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted range-bearing of ``marks (k, 2)`` from the poses ``pose ∘ rel (k, 3)``.

    Returns ``(z (k, 2), J (k, 2, 3))`` (Jacobian w.r.t. ``pose``) and the
    Jacobians ``(k, 2, 3)`` w.r.t. each reading's own pose."""
    heads = pose[2] + rel[:, 2]
    arm = _rot(np.full(len(rel), pose[2])) @ rel[:, :2, None]  # (k, 2, 1)
    sensor_arm = _rot(heads) @ offset  # (k, 2)
    d = marks - (pose[:2] + arm[:, :, 0] + sensor_arm)
    q = np.einsum("ki,ki->k", d, d)
    rng = np.sqrt(q)
    z = np.stack([rng, np.arctan2(d[:, 1], d[:, 0]) - heads], 1)
    dr = -d / rng[:, None]  # d range / d sensor position
    db = np.stack([d[:, 1], -d[:, 0]], 1) / q[:, None]  # d bearing / d sensor position
    perp_own = np.stack([-sensor_arm[:, 1], sensor_arm[:, 0]], 1)  # d sensor / d own heading
    perp = perp_own + np.stack([-arm[:, 1, 0], arm[:, 0, 0]], 1)  # ... / d pose heading
    j_own = np.empty((len(rel), 2, 3))
    j_own[:, 0, :2], j_own[:, 1, :2] = dr, db
    j_own[:, 0, 2] = np.einsum("ki,ki->k", dr, perp_own)
    j_own[:, 1, 2] = np.einsum("ki,ki->k", db, perp_own) - 1.0
    j = j_own.copy()
    j[:, 0, 2] = np.einsum("ki,ki->k", dr, perp)
    j[:, 1, 2] = np.einsum("ki,ki->k", db, perp) - 1.0
    return z, j, j_own


def _starts(rel, marks, z, r, offset, count: int = _STARTS) -> np.ndarray:
    """The poses (at the reference time) that best explain the readings for each heading
    of :data:`_HEADINGS`, best ``count`` of them: each reading puts the robot at
    one point once the heading is given; the spread of those points scores it."""
    heads = _HEADINGS[:, None] + rel[None, :, 2]  # (H, k)
    ray = heads + z[None, :, 1]
    sensor = marks[None] - z[None, :, 0, None] * np.stack([np.cos(ray), np.sin(ray)], -1)
    c, s = np.cos(heads), np.sin(heads)
    own = sensor - np.stack([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]], -1)
    ch, sh = np.cos(_HEADINGS)[:, None], np.sin(_HEADINGS)[:, None]
    arm = np.stack([ch * rel[None, :, 0] - sh * rel[None, :, 1],
                    sh * rel[None, :, 0] + ch * rel[None, :, 1]], -1)
    ref = own - arm  # (H, k, 2)
    w = 1.0 / (r[:, 0, 0] + z[:, 0] ** 2 * r[:, 1, 1])  # (k,) position weight of each reading
    mean = np.einsum("hki,k->hi", ref, w) / w.sum()
    cost = np.einsum("hki,k->h", (ref - mean[:, None]) ** 2, w)
    best = np.argsort(cost)[:count]
    return np.column_stack([mean[best], _HEADINGS[best]])


def _innovation(
    pose: np.ndarray, rel: np.ndarray, marks: np.ndarray, z: np.ndarray, offset: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Readings minus their prediction at ``pose`` (bearings wrapped), with the Jacobians
    of :func:`_predict`."""
    pred, j, j_own = _predict(pose, rel, marks, offset)
    nu = z - pred
    nu[:, 1] = _wrap(nu[:, 1])
    return nu, j, j_own


def _linearize(
    pose: np.ndarray, rel: np.ndarray, marks: np.ndarray, z: np.ndarray, r: np.ndarray,
    q: np.ndarray, offset: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Innovation, Jacobian, inverse innovation covariances and the information matrix of
    the reference pose at ``pose``."""
    nu, j, j_own = _innovation(pose, rel, marks, z, offset)
    s_inv = np.linalg.inv(r + j_own @ q @ np.swapaxes(j_own, 1, 2))
    info = np.einsum("kai,kab,kbj->ij", j, s_inv, j)
    return nu, j, s_inv, info


def fit_candidates(
    rel: np.ndarray,
    marks: np.ndarray,
    z: np.ndarray,
    r: np.ndarray,
    q: np.ndarray,
    offset: np.ndarray,
    iterations: int = 10,
    starts: int = _STARTS,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """The local optima of :func:`fit_pose`'s problem reached from its ``starts`` best
    starting headings: ``(pose, covariance, chi-square)`` each, in the order tried."""
    found = []
    for pose in _starts(rel, marks, z, r, offset, starts):
        for _ in range(iterations):
            nu, j, s_inv, info = _linearize(pose, rel, marks, z, r, q, offset)
            if not np.all(np.isfinite(info)) or np.linalg.cond(info) > 1e12:
                break
            step = np.linalg.solve(info, np.einsum("kai,kab,kb->i", j, s_inv, nu))
            pose = pose + step
            pose[2] = _wrap(pose[2])
            if np.abs(step).max() < 1e-6:
                break
        else:
            nu, j, s_inv, info = _linearize(pose, rel, marks, z, r, q, offset)
        if not np.all(np.isfinite(info)) or np.linalg.cond(info) > 1e12:
            continue
        nu = _innovation(pose, rel, marks, z, offset)[0]
        chi = float(np.einsum("ka,kab,kb->", nu, s_inv, nu))
        found.append((pose.copy(), np.linalg.inv(info), chi))
    return found


def fit_pose(
    rel: np.ndarray,
    marks: np.ndarray,
    z: np.ndarray,
    r: np.ndarray,
    q: np.ndarray,
    offset: np.ndarray,
    iterations: int = 10,
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The pose at a reference time that best explains range-bearing readings of landmarks.

    Reading ``k`` was taken at the pose ``pose ∘ rel[k]`` (``rel``: its pose relative
    to the reference one by odometry, ``(k, 3)``) of the landmark at ``marks[k]``:
    ``z[k] = (range, bearing)`` with noise ``r[k] (2, 2)``; ``q[k] (3, 3)`` is the
    odometry's noise between the reading and the reference time, ``offset (2,)`` the
    sensor's position on the robot. Gauss-Newton from the best of a sweep of headings.

    Returns ``(pose (3,), covariance (3, 3), chi-square of the residuals)``, or ``None``
    when the readings do not fix a pose.
    """
    best = None
    for fit in fit_candidates(rel, marks, z, r, q, offset, iterations):
        if best is None or fit[2] < best[2]:
            best = fit
    return best


def residuals(
    pose: np.ndarray, rel: np.ndarray, marks: np.ndarray, z: np.ndarray, r: np.ndarray,
    q: np.ndarray, offset: np.ndarray,
) -> np.ndarray:
    """Each reading's chi-square ``(k,)`` at the reference pose ``pose`` (the arguments of
    :func:`fit_pose`)."""
    nu, _, j_own = _innovation(np.asarray(pose, dtype=float), rel, marks, z, offset)
    s = r + j_own @ q @ np.swapaxes(j_own, 1, 2)
    return np.einsum("ka,kab,kb->k", nu, np.linalg.inv(s), nu)


@dataclass
class _Reading:
    time: float
    row: np.ndarray  # the odometry track's table row at the reading's time
    landmark: Hashable
    mark: np.ndarray
    z: np.ndarray
    r: np.ndarray
    d2: float  # its gate statistic (chi-square, 2 dof)
    rejected: bool


class Relocalizer:
    """Each robot's recent landmark readings, and when they prove its filter lost.

    Args:
        n: number of robots.
        motion: ``motion(row_a, row_b, heading_a) -> (delta (3,), q (3, 3))``, the
            odometry between two table rows (:meth:`OdometryTrack.motion`).
        min_readings: readings of the landmarks that refute the belief, at least
            (``None``: never recover).
        min_landmarks: landmarks whose readings the fitted pose explains better than the
            belief does, at least.
        min_baseline: the largest distance between two of them (m), at least.
        window_s: readings older than this (s) are forgotten.
        max_turn_rate: readings taken while turning faster (rad/s) are not kept.
        agree_prob: probability of the chi-square tests (the readings agree on one
            pose; that pose is not the belief's).
        max_std: the largest position std (m) and heading std (rad) of the fitted pose.
        suspect_prob: a landmark's readings are suspect when their mean gate statistic is
            above this quantile of the chi-square distribution of 2 dof.
        check_every_s: after an accepted reading, a robot's readings are looked into at
            most this often (s).
        consensus: also search the readings for a pose they agree on, far from the
            belief, whatever their gate statistics (:meth:`_consensus`).
        min_jump: how far (m) that pose must be from the belief, at least.
        consensus_std: the largest position std (m) and heading std (rad) of that pose.
        min_places: the fewest places (groups of landmarks, ``min_baseline`` apart) that
            the readings of that search must come from.
        min_ratio: how many times worse than that pose the belief must explain them
            (chi-square ratio: a test a model too confident or too generous passes alike).
    """

    def __init__(
        self,
        n: int,
        motion: Callable[[np.ndarray, np.ndarray, float], tuple[np.ndarray, np.ndarray]],
        min_readings: int | None = 3,
        min_landmarks: int = 2,
        min_baseline: float = 1.0,
        window_s: float = 10.0,
        max_turn_rate: float = 0.1,
        agree_prob: float = 0.999,
        max_std: tuple[float, float] = (1.0, 0.2),
        check_every_s: float = 0.5,
        suspect_prob: float = 0.9,
        consensus: bool = True,
        min_jump: float = 1.5,
        consensus_std: tuple[float, float] = (1.5, 0.3),
        min_places: int = 2,
        min_ratio: float = 4.0,
    ) -> None:
        if min_readings is not None and (
            isinstance(min_readings, bool) or not isinstance(min_readings, int | np.integer)
            or min_readings < 1
        ):
            raise ValueError(f"min_readings must be a positive int or None, got {min_readings!r}")
        if isinstance(min_landmarks, bool) or not isinstance(min_landmarks, int | np.integer) \
                or min_landmarks < 2:
            raise ValueError(f"min_landmarks must be an int >= 2, got {min_landmarks!r}")
        for name, value in (("window_s", window_s), ("max_turn_rate", max_turn_rate)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not (np.isfinite(min_baseline) and min_baseline >= 0):
            raise ValueError(f"min_baseline must be finite and >= 0, got {min_baseline!r}")
        self.min_baseline = float(min_baseline)
        chi2_threshold(agree_prob, 1)
        if len(max_std) != 2 or not all(np.isfinite(v) and v > 0 for v in max_std):
            raise ValueError(f"max_std must be two finite values > 0, got {max_std!r}")
        self.motion = motion
        self.min_readings = min_readings
        self.min_landmarks = int(min_landmarks)
        self.window_s = float(window_s)
        self.max_turn_rate = float(max_turn_rate)
        self.agree_prob = float(agree_prob)
        self.max_std = (float(max_std[0]), float(max_std[1]))
        if not (np.isfinite(check_every_s) and check_every_s >= 0):
            raise ValueError(f"check_every_s must be finite and >= 0, got {check_every_s!r}")
        self.check_every_s = float(check_every_s)
        self.suspect_d2 = chi2_threshold(suspect_prob, 2)
        if not (np.isfinite(min_jump) and min_jump > 0):
            raise ValueError(f"min_jump must be finite and > 0, got {min_jump!r}")
        if len(consensus_std) != 2 or not all(np.isfinite(v) and v > 0 for v in consensus_std):
            raise ValueError(f"consensus_std must be two finite values > 0, got {consensus_std!r}")
        if isinstance(min_places, bool) or not isinstance(min_places, int | np.integer) \
                or min_places < 2:
            raise ValueError(f"min_places must be an int >= 2, got {min_places!r}")
        self.min_places = int(min_places)
        if not (np.isfinite(min_ratio) and min_ratio >= 1):
            raise ValueError(f"min_ratio must be finite and >= 1, got {min_ratio!r}")
        self.min_ratio = float(min_ratio)
        self.consensus = bool(consensus)
        self.min_jump = float(min_jump)
        self.consensus_std = (float(consensus_std[0]), float(consensus_std[1]))
        self._searched = np.full(int(n), -np.inf)
        self._readings: list[list[_Reading]] = [[] for _ in range(int(n))]
        self._checked = np.full(int(n), -np.inf)
        self.recoveries = 0

    @property
    def enabled(self) -> bool:
        """Whether this ever recovers."""
        return self.min_readings is not None

    def clear(self, i: int) -> None:
        """Forget robot ``i``'s readings (its belief was just replaced by them)."""
        self._readings[i].clear()

    def add(
        self, i: int, time: float, row: np.ndarray, turn_rate: float, landmark: Hashable,
        mark: np.ndarray, z: np.ndarray, r: np.ndarray, d2: float, rejected: bool,
    ) -> None:
        """Keep a reading ``z`` (noise ``r``) of robot ``i`` of the landmark named
        ``landmark`` at ``mark``, its gate statistic ``d2`` and whether the gate
        ``rejected`` it; ``row``: the robot's odometry table row at ``time``;
        ``turn_rate``: its turn rate then."""
        if not self.enabled:
            return
        keep = self._readings[i]
        while keep and keep[0].time < time - self.window_s:
            keep.pop(0)
        if abs(turn_rate) > self.max_turn_rate:
            return
        keep.append(_Reading(float(time), np.array(row, dtype=float), landmark,
                             np.array(mark, dtype=float), np.array(z, dtype=float),
                             np.array(r, dtype=float), float(d2), bool(rejected)))

    def propose(
        self, i: int, offset: np.ndarray, mean: np.ndarray, cov: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The pose ``(3,)`` and covariance ``(3, 3)``, at robot ``i``'s newest kept reading,
        that its kept readings agree on, when that pose refutes the belief ``mean``,
        ``cov``; ``None`` otherwise.

        Looked into when the mean gate statistics of the readings of ``min_landmarks``
        landmarks, two of them ``min_baseline`` apart, are above the ``suspect_prob``
        quantile of one reading's: after a rejected reading, and at most every
        ``check_every_s`` after an accepted one (a belief that has settled on a wrong
        pose, where readings still pass the gate one by one, but narrowly). With
        ``consensus``, the readings are also searched every ``check_every_s`` for a pose
        far from the belief that they agree on without any one of their landmarks
        (:meth:`_consensus`), whatever their gate statistics."""
        keep = self._readings[i]
        if not self.enabled or len(keep) < 3:
            return None
        newest = keep[-1]
        suspect = (newest.rejected or newest.time - self._checked[i] >= self.check_every_s) \
            and self._suspects(keep)
        search = self.consensus and newest.time - self._searched[i] >= self.check_every_s
        if not (suspect or search):
            return None
        window = self._window(keep, offset)
        fix = None
        if suspect:
            self._checked[i] = newest.time
            fix = self._refute(keep, window, mean, cov)
        if fix is None and search:
            self._searched[i] = newest.time
            fix = self._consensus(keep, window, mean)
        return fix

    def _window(self, keep: list[_Reading], offset: np.ndarray) -> tuple[np.ndarray, ...]:
        """The arguments of :func:`fit_pose` for the kept readings, referred to the newest."""
        marks = np.array([k.mark for k in keep])
        last = keep[-1].row
        rel = np.empty((len(keep), 3))
        q = np.empty((len(keep), 3, 3))
        for k, reading in enumerate(keep):
            # Pose of reading k in the frame of the newest one, by odometry (motion from
            # the newest back to it, the newest heading taken as 0), and the noise of the
            # motion between them (integrated forward: the noise integrals only grow).
            rel[k] = self.motion(last, reading.row, 0.0)[0]
            q[k] = self.motion(reading.row, last, float(rel[k, 2]))[1]
        z = np.array([k.z for k in keep])
        r = np.array([k.r for k in keep])
        return rel, marks, z, r, q, np.asarray(offset, dtype=float)

    def _refute(
        self, keep: list[_Reading], window: tuple[np.ndarray, ...], mean: np.ndarray,
        cov: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The fitted pose of suspect readings when it passes the tests of the module doc."""
        fit = fit_pose(*window)
        if fit is None:
            return None
        pose, p_fit, chi = fit
        if chi > chi2_threshold(self.agree_prob, 2 * len(keep) - 3):
            return None
        if np.linalg.eigvalsh(p_fit[:2, :2])[-1] > self.max_std[0] ** 2 \
                or p_fit[2, 2] > self.max_std[1] ** 2:
            return None
        gain = residuals(mean, *window) - residuals(pose, *window)
        if not self._contradicted(keep, gain):
            return None
        d = pose - mean
        d[2] = _wrap(d[2])
        if d @ np.linalg.solve(cov + p_fit, d) <= chi2_threshold(self.agree_prob, 3):
            return None
        return pose, p_fit

    def _consensus(
        self, keep: list[_Reading], window: tuple[np.ndarray, ...], mean: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The pose all kept readings agree on, when it is ``min_jump`` or more from the
        belief ``mean`` and refutes it without any one landmark's readings.

        The readings must come from ``min_places`` places. The pose is the best local
        optimum of the fit from :data:`_CONSENSUS_STARTS` headings; it must explain every
        reading (chi-square test at ``agree_prob``), be determined within
        ``consensus_std``, beat every other optimum ``min_jump`` or more away by the
        ``agree_prob`` bound of 3 dof (two poses the readings cannot tell apart: no
        verdict), and explain the readings ``min_ratio`` times better than the belief.
        Dropping the readings of any one landmark, those left must still favour it over
        the belief by that bound: a biased or misidentified landmark is one landmark."""
        if _places(np.unique(window[1], axis=0), self.min_baseline) < self.min_places:
            return None
        margin = chi2_threshold(self.agree_prob, 3)
        at_belief = residuals(mean, *window)
        if _without_worst(keep, at_belief) <= margin:
            return None  # no pose can gain that much on the readings of the others
        fits = sorted(fit_candidates(*window, starts=_CONSENSUS_STARTS), key=lambda f: f[2])
        if not fits:
            return None
        pose, p_fit, chi = fits[0]
        if chi > chi2_threshold(self.agree_prob, 2 * len(keep) - 3):
            return None
        if np.linalg.eigvalsh(p_fit[:2, :2])[-1] > self.consensus_std[0] ** 2 \
                or p_fit[2, 2] > self.consensus_std[1] ** 2:
            return None
        if np.hypot(*(pose[:2] - mean[:2])) < self.min_jump:
            return None
        for other in fits[1:]:
            if np.hypot(*(other[0][:2] - pose[:2])) >= self.min_jump \
                    and other[2] - chi <= margin:
                return None
        fitted = residuals(pose, *window)
        gain = at_belief - fitted
        if gain.sum() < (self.min_ratio - 1.0) * fitted.sum():
            return None
        per: dict[Hashable, float] = {}
        for k, g in zip(keep, gain.tolist(), strict=True):
            per[k.landmark] = per.get(k.landmark, 0.0) + g
        total = sum(per.values())
        if len(per) < 2 or any(total - g <= margin for g in per.values()):
            return None
        return pose, p_fit

    def _suspects(self, keep: list[_Reading]) -> bool:
        """Whether ``min_landmarks`` landmarks, two of them ``min_baseline`` apart, have a
        mean gate statistic above the ``suspect_prob`` quantile of the chi-square
        distribution of 2 dof (a cheap test before the fit, which an accurate filter passes
        only by chance)."""
        total: dict[Hashable, float] = {}
        count: dict[Hashable, int] = {}
        marks: dict[Hashable, np.ndarray] = {}
        for k in keep:
            total[k.landmark] = total.get(k.landmark, 0.0) + k.d2
            count[k.landmark] = count.get(k.landmark, 0) + 1
            marks[k.landmark] = k.mark
        odd = [lm for lm, t in total.items() if t > count[lm] * self.suspect_d2]
        return len(odd) >= self.min_landmarks and _spread(np.array([marks[lm] for lm in odd])) \
            >= self.min_baseline

    def _contradicted(self, keep: list[_Reading], gain: np.ndarray) -> bool:
        """Whether the fitted pose explains the readings of ``min_landmarks`` landmarks, two
        of them ``min_baseline`` apart and ``min_readings`` readings in all, better than the
        belief (chi-square gain ``gain (k,)`` per reading, summed per landmark, above the
        bound of 2 dof). A landmark read once is no verdict (one outlier would do)."""
        total: dict[Hashable, float] = {}
        count: dict[Hashable, int] = {}
        marks: dict[Hashable, np.ndarray] = {}
        for k, g in zip(keep, gain.tolist(), strict=True):
            total[k.landmark] = total.get(k.landmark, 0.0) + g
            count[k.landmark] = count.get(k.landmark, 0) + 1
            marks[k.landmark] = k.mark
        bound = chi2_threshold(self.agree_prob, 2)
        against = [lm for lm, g in total.items() if g > bound and count[lm] >= 2]
        if len(against) < self.min_landmarks \
                or sum(count[lm] for lm in against) < self.min_readings:
            return False
        return _spread(np.array([marks[lm] for lm in against])) >= self.min_baseline


def _without_worst(keep: list[_Reading], values: np.ndarray) -> float:
    """The sum of ``values (k,)``, one per kept reading, less that of the landmark whose
    readings sum highest."""
    per: dict[Hashable, float] = {}
    for k, v in zip(keep, values.tolist(), strict=True):
        per[k.landmark] = per.get(k.landmark, 0.0) + v
    return sum(per.values()) - max(per.values())


def _places(points: np.ndarray, apart: float) -> int:
    """How many groups ``points (k, 2)`` form, points closer than ``apart`` grouped."""
    group = np.arange(len(points))
    near = np.linalg.norm(points[:, None] - points[None], axis=-1) < apart
    for _ in range(len(points)):
        merged = np.where(near, group[None, :], len(points)).min(axis=1)
        if np.array_equal(merged, group):
            break
        group = merged
    return len(np.unique(group))


def _spread(points: np.ndarray) -> float:
    """The largest distance between two of ``points (k, 2)``."""
    return float(np.linalg.norm(points[:, None] - points[None], axis=-1).max())
