"""Resampling helpers of the particle filter: low-variance (systematic) resampling,
the KLD-sampling bound (Fox 2003) on the number of particles, and the compiled
resampling of a :class:`~estimators.mcl.team.ParticleTeam` at once (:func:`resample_team`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
from scipy.special import ndtri

from estimators.mcl._team_kernels import (
    build_blocks,
    normals_from_bits,
    select_blocks,
    ziggurat_tables,
)
from estimators.mcl.team import ParticleTeam, TeamMember

__all__ = [
    "kld_need", "kld_sample_bound", "low_variance_from_cumulative", "low_variance_indices",
    "resample_team", "standard_normals",
]

_ZIGGURAT = ziggurat_tables()
_NO_BITS = np.zeros(0, dtype=np.uint64)
_NO_NEED = np.zeros(1)
_NO_XY = np.zeros((0, 2))
_NO_H = np.zeros(0)
_NO_KLD = np.zeros((1, 8))


def standard_normals(rng: np.random.Generator, out: np.ndarray) -> np.ndarray:
    """Fill the float32 array ``out`` with standard normals from ``rng``'s bit stream and
    return it (the ziggurat method in one compiled pass; about twice as fast as
    ``rng.standard_normal(dtype=np.float32)``, from a different stream)."""
    n = out.size
    extra = 16 + n // 16  # about 1.3 % of the tries need another word
    while True:
        raw = rng.bit_generator.random_raw(n + extra)
        if normals_from_bits(raw, out, *_ZIGGURAT) >= 0:
            return out
        extra *= 2


def low_variance_indices(weights: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Low-variance (systematic) resampling: ``n`` sorted indices drawn in proportion to weights.

    One uniform offset ``u``, ``n`` equally spaced pointers ``(u + j) / n`` of the
    cumulative weight; particle ``i`` is copied once per pointer that falls in
    its cumulative interval. O(n + len(weights)) via ``np.repeat``.
    ``weights`` must be non-negative with a positive finite sum.
    """
    weights = np.asarray(weights, dtype=float)
    if weights.ndim != 1 or weights.size == 0:
        raise ValueError(f"weights must be a non-empty 1D array, got shape {weights.shape}")
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    cum = np.add.accumulate(weights)
    total = cum[-1]
    if not np.isfinite(total) or total <= 0 or weights.min() < 0:
        raise ValueError(
            f"weights must be non-negative with a positive finite sum, got sum={total}"
        )
    return low_variance_from_cumulative(cum, n, rng)


def low_variance_from_cumulative(cum: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Core of :func:`low_variance_indices` from the cumulative weights (no checks)."""
    total = cum[-1]
    u = rng.random()
    # number of pointers strictly below each cumulative weight (rounding may push
    # it past n, which no pointer sees)
    below = cum * (n / total)
    below -= u
    np.ceil(below, out=below)  # >= 0 since u < 1
    below_i = below.astype(np.intp)
    below_i[-1] = n
    # pointer j goes to the number of particles whose interval ends at or before it
    return np.add.accumulate(np.bincount(below_i, minlength=n + 1)[:n])


def kld_sample_bound(k: np.ndarray, epsilon: float, delta: float) -> np.ndarray:
    """Samples needed for KLD-sampling with ``k`` occupied bins (Fox 2003, Wilson-Hilferty).

    ``n = (k-1)/(2 eps) * (1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) z_{1-delta})^3``;
    1 for ``k <= 1``.
    """
    k = np.asarray(k, dtype=float)
    z = ndtri(1.0 - delta)
    km1 = np.maximum(k - 1.0, 1.0)
    a = 2.0 / (9.0 * km1)
    n = km1 / (2.0 * epsilon) * (1.0 - a + np.sqrt(a) * z) ** 3
    return np.where(k <= 1, 1.0, np.ceil(n))


@lru_cache(maxsize=32)
def kld_need(epsilon: float, delta: float, n_min: int, n_max: int) -> np.ndarray:
    """``max(kld_sample_bound(k), n_min)`` for ``k = 0 .. n_max`` (read-only, cached)."""
    need = np.maximum(kld_sample_bound(np.arange(n_max + 1), epsilon, delta), n_min)
    need.flags.writeable = False
    return need


def resample_team(team: ParticleTeam, w: np.ndarray, which: Sequence[bool]) -> np.ndarray:
    """:meth:`~estimators.mcl.filter.ParticleFilter.resample` of robot ``r`` where
    ``which[r]``, all in two compiled passes over the team's arrays; returns the team's
    new state (block layout), which every set's state is then a view of (resampled sets
    get uniform weights).

    ``w``: the team's weights (:meth:`ParticleTeam.weights`). Each robot draws from its
    own generator in the order :meth:`~estimators.mcl.filter.ParticleFilter.resample`
    documents, so resampling a team equals resampling its filters one by one.
    """
    filters, flat, ends = team.members, team.state, team.ends
    ints, u, p_inj, kld, words, needs = _first_draws(team, which)
    nr = len(filters)
    mode_a, m_a, n_inj_a = np.array(ints, dtype=np.intp).reshape(nr, 3).T.copy()
    if words:  # KLD robots' shuffle words at their offsets
        offsets = np.cumsum(m_a) - m_a
        bits = np.zeros(int(m_a.sum()), dtype=np.uint64)
        for r, word in words:
            bits[offsets[r]:offsets[r] + m_a[r]] = word
        need_all = np.concatenate(needs)
    else:
        bits = _NO_BITS
        need_all = _NO_NEED
    if not w.flags.writeable:  # one compiled signature: writeable arrays
        w = w.copy()
    idx, counts = select_blocks(flat, w, ends, mode_a, np.array(u), m_a, bits,
                                _NO_KLD if kld is None else kld, need_all)
    keep = counts if words else m_a
    xy_all, h_all = _injections(filters, ints, p_inj, counts, keep, n_inj_a)
    new, new_ends = build_blocks(flat, ends, mode_a, idx, m_a, keep, xy_all, h_all, n_inj_a,
                                 team.origins)
    start = 0
    for pf, ps, end, (mode, _, _) in zip(filters, team.sets, new_ends.tolist(), ints,
                                         strict=True):
        ps.state = new[3 * start:3 * end].reshape(3, end - start)
        ps.state_start = start
        if mode:
            ps.weights = pf.uniform_weights(end - start)
        start = end
    team.state, team.ends = new, new_ends
    return new


def _first_draws(team: ParticleTeam, which: Sequence[bool]) -> tuple:
    """The draws of :func:`resample_team` before its selection pass, robot by robot: per
    robot ``(mode, indices to draw, injected count)`` (mode 0 keep, 1 fixed count,
    2 KLD), the resampling offsets, injection probabilities, the KLD rows of
    ``select_blocks`` (None: no KLD robot), the KLD robots' shuffle words and the KLD
    bounds."""
    nr = len(team.members)
    ints = [(0, 0, 0)] * nr
    u = [0.0] * nr
    p_inj = [0.0] * nr
    kld: np.ndarray | None = None
    words: list[tuple[int, np.ndarray]] = []
    needs: list[np.ndarray] = []
    need_off = 0
    start = 0
    for r, (pf, ps, end) in enumerate(zip(team.members, team.sets, team.ends.tolist(),
                                          strict=True)):
        n, start = end - start, end
        if not which[r]:
            continue
        cfg = pf.config
        rng = pf.rng
        p = p_inj[r] = pf.inject_probability
        if cfg.adaptive:
            u[r] = rng.random()
            words.append((r, rng.bit_generator.random_raw(cfg.n_max)))  # the shuffle
            ints[r] = (2, cfg.n_max, 0)
            if ps.unwrapped_steps:
                ps.wrap_headings()
            bx, by, bt = cfg.kld_bin
            need = kld_need(cfg.kld_epsilon, cfg.kld_delta, cfg.n_min, cfg.n_max)
            if kld is None:
                kld = np.zeros((nr, 8))
            kld[r] = (ps.origin_xy[0], ps.origin_xy[1], 1.0 / bx, 1.0 / by, 1.0 / bt,
                      math.ceil(2.0 * math.pi / bt), need_off, cfg.n_min)
            needs.append(need)
            need_off += need.size
        else:
            k = int(rng.binomial(n, p)) if p > 0 else 0
            u[r] = rng.random()
            ints[r] = (1, n - k, k)
    return ints, u, p_inj, kld, words, needs


def _injections(filters: Sequence[TeamMember], ints: list[tuple[int, int, int]],
                p_inj: list[float], counts: np.ndarray, keep: np.ndarray,
                n_inj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The injected particles' positions ``(K, 2)`` and headings ``(K,)`` of every robot in
    turn; a KLD robot's injected count is drawn here from its selected count (``keep`` and
    ``n_inj`` are updated in place)."""
    inj_xy: list[np.ndarray] = []
    inj_h: list[np.ndarray] = []
    for r, pf in enumerate(filters):
        mode, _, k = ints[r]
        if mode == 2 and p_inj[r] > 0:
            n = int(counts[r])
            k = n_inj[r] = int(pf.rng.binomial(n, p_inj[r]))
            keep[r] = n - k
        if k:  # uniform over free space (OccupancyGrid.sample_free's draws), any heading
            inj_xy.append(pf.grid.sample_free(k, pf.rng))
            inj_h.append(pf.rng.uniform(-np.pi, np.pi, size=k))
    if len(inj_xy) > 1:
        return np.concatenate(inj_xy), np.concatenate(inj_h)
    return (inj_xy[0], inj_h[0]) if inj_xy else (_NO_XY, _NO_H)
