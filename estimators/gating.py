"""Validation gates and what to do when they lock a filter out.

:func:`chi2_threshold` is the chi-square gate; :class:`GateMonitor` counts
consecutive rejections per robot and sensor channel and says when a filter
should stop trusting itself over the sensor; :func:`observed_inflation` is
the covariance widening such a recovery applies.
"""

from __future__ import annotations

from collections.abc import Hashable

import numpy as np
from scipy.stats import chi2

_CHI2_CACHE: dict[tuple[float, int], float] = {}


def chi2_threshold(prob: float, dof: int) -> float:
    """Chi-square gate threshold: the ``prob`` quantile with ``dof`` degrees of freedom."""
    if not 0.0 < prob < 1.0:
        raise ValueError(f"gate probability must be in (0, 1), got {prob!r}")
    key = (float(prob), int(dof))
    if key not in _CHI2_CACHE:
        _CHI2_CACHE[key] = float(chi2.ppf(prob, dof))
    return _CHI2_CACHE[key]


# Probability of the chi-square test that says two rejected readings agree.
AGREE_PROB = 0.999


class GateMonitor:
    """Consecutive gate rejections per robot and sensor channel, and when to recover.

    :meth:`record` takes a batch of gate decisions of one channel and returns
    which rejected readings end a run of ``recover_after`` consecutive
    rejections (counting the current one) that agree with each other; those
    counters restart at zero.
    ``recover_after=None`` never recovers. A recovery is counted in
    :attr:`recoveries`.
    """

    def __init__(self, n: int, recover_after: int | None = 3) -> None:
        if recover_after is not None and (
            isinstance(recover_after, bool) or not isinstance(recover_after, int | np.integer)
            or recover_after < 1
        ):
            raise ValueError(f"recover_after must be a positive int or None, got {recover_after!r}")
        self.n = int(n)
        self.recover_after = recover_after
        self.counts: dict[Hashable, np.ndarray] = {}
        # Per channel: the last rejected innovation of each robot and its covariance.
        self._last: dict[Hashable, tuple[np.ndarray, np.ndarray]] = {}
        self.recoveries = 0

    def pending(self, channel: Hashable, any_rejected: bool) -> bool:
        """Whether :meth:`record` has anything to do for a batch of ``channel``: some
        reading was rejected, or some robot's count is running (a cheap test for the
        common all-accepted batch)."""
        if self.recover_after is None:
            return False
        counts = self.counts.get(channel)
        return any_rejected or (counts is not None and bool(counts.any()))

    def record(
        self,
        channel: Hashable,
        idx: np.ndarray,
        accepted: np.ndarray,
        nu: np.ndarray | None = None,
        s: np.ndarray | None = None,
        angles: tuple[int, ...] = (),
    ) -> np.ndarray:
        """Update the counters of robots ``idx`` (distinct) on ``channel``; returns the
        mask of ``idx`` that must recover now.

        With the innovations ``nu (k, m)`` and their covariances ``s (k, m, m)``,
        a rejection extends a run only when its innovation agrees with the run's
        previous one (chi-square test on the difference, covariance ``S + S_prev``,
        at :data:`AGREE_PROB`; components ``angles`` wrapped): a filter that has
        drifted sees the same innovation again and again, while outliers (multipath
        fixes) scatter, so a run of them does not trigger a recovery.
        """
        if self.recover_after is None:
            return np.zeros(len(idx), dtype=bool)
        counts = self.counts.get(channel)
        if counts is None:
            counts = self.counts[channel] = np.zeros(self.n, dtype=int)
        prev = counts[idx]
        c = np.where(accepted, 0, prev + 1)
        if nu is not None and s is not None:
            m = nu.shape[1]
            last = self._last.get(channel)
            if last is None or last[0].shape[1] != m:
                last = self._last[channel] = (np.zeros((self.n, m)), np.zeros((self.n, m, m)))
            rejected = ~np.asarray(accepted, dtype=bool)
            rows = np.nonzero(rejected & (prev > 0))[0]
            if len(rows):
                robots = idx[rows]
                d = nu[rows] - last[0][robots]
                for a in angles:
                    d[:, a] = (d[:, a] + np.pi) % (2 * np.pi) - np.pi
                joint = s[rows] + last[1][robots]
                d2 = np.einsum("ki,kij,kj->k", d, np.linalg.pinv(joint), d)
                c[rows[~(d2 <= chi2_threshold(AGREE_PROB, m))]] = 1  # disagrees: a new run
            last[0][idx[rejected]] = nu[rejected]
            last[1][idx[rejected]] = s[rejected]
        recover = c >= self.recover_after
        c[recover] = 0
        counts[idx] = c
        self.recoveries += int(np.count_nonzero(recover))
        return recover

    def record_one(self, channel: Hashable, i: int, accepted: bool) -> bool:
        """:meth:`record` of one reading of robot ``i``; returns whether to recover now."""
        if self.recover_after is None:
            return False
        counts = self.counts.get(channel)
        if counts is None:
            counts = self.counts[channel] = np.zeros(self.n, dtype=int)
        if accepted:
            counts[i] = 0
            return False
        counts[i] += 1
        if counts[i] < self.recover_after:
            return False
        counts[i] = 0
        self.recoveries += 1
        return True


def observed_inflation(p: np.ndarray, h: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """What to add to covariances ``p (k, d, d)`` so that the part a sensor with Jacobian
    ``h`` (``(k, m, d)`` or one ``(m, d)``) observes grows by ``factor (k,)`` (>= 1):
    ``(factor - 1) P H^T (H P H^T)^-1 H P``, so ``H P H^T`` becomes ``factor`` times
    itself while directions the sensor cannot see keep their spread."""
    ph_t = p @ np.swapaxes(h, -1, -2)
    s = h @ ph_t
    gain = ph_t @ np.linalg.pinv(s)
    scale = np.maximum(np.asarray(factor, dtype=float), 1.0) - 1.0
    return _symmetrize(scale[:, None, None] * (gain @ np.swapaxes(ph_t, -1, -2)))


def _symmetrize(p: np.ndarray) -> np.ndarray:
    return 0.5 * (p + np.swapaxes(p, -1, -2))
