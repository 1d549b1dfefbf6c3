"""Weighting one or several particle filters in one compiled pass.

:func:`weigh_team` multiplies each filter's weights by its scan likelihood
(a likelihood-field laser scan scored in the pass, or scan log-likelihoods
scored before, e.g. by the beam model's tables) and its DGPS / compass fixes
(:func:`estimators.mcl._team_kernels.weigh_blocks`), normalizes them, and updates
the filters' augmented-MCL averages. :class:`~estimators.mcl.filter.ParticleFilter`
uses it for one filter, :mod:`estimators.mcl.batch` for a team.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.geometry import wrap_angle
from estimators.mcl._team_kernels import weigh_blocks
from estimators.mcl.team import ParticleSet, ParticleTeam

__all__ = ["NO_FIELD", "weigh_team"]

# placeholders of the likelihood-field arguments of weigh_blocks when no field is read
NO_FIELD = (np.zeros(1, dtype=np.float32), 1, 0, np.float32(0), np.float32(1), np.float32(0),
            np.float32(0), np.float32(0), np.float32(0))


def weigh_team(
    team: ParticleTeam, w_prev: np.ndarray, fixes: np.ndarray, nb: np.ndarray,
    loglik: np.ndarray, scored: bool, offsets: np.ndarray, n_eff: np.ndarray,
    lf_args: tuple = NO_FIELD, ux: np.ndarray | None = None, uy: np.ndarray | None = None,
    power: float = 1.0,
) -> np.ndarray:
    """Weight ``team`` (weights ``w_prev``: :meth:`ParticleTeam.weights`, or a team of
    one's own) by the scans and ``fixes`` (rows of
    :meth:`~estimators.mcl.filter.ParticleFilter.fix_row`).

    Robot ``r`` has a scan when ``nb[r] >= 0``: with ``scored`` its log-likelihoods
    are ``loglik``'s segment, otherwise ``nb[r]`` likelihood-field endpoints ``ux, uy``
    scored in the pass (``lf_args``: :meth:`ParticleFilter.lf_kernel_args`, ``power``:
    the field's power) into ``loglik``. Its scan's log evidence is the pass's plus
    ``offsets[r]``; the augmented-MCL averages track it over ``n_eff[r]`` beams
    (none when 0). Returns the log evidences (NaN: no scan).
    """
    filters, flat, ends = team.members, team.state, team.ends
    nr = len(filters)
    evidence = np.full(nr, np.nan)
    if not nr:
        return evidence
    w = np.empty(w_prev.size)
    res = np.empty((nr, 3))
    if ux is None:
        ux = uy = np.zeros((nr, 0), dtype=np.float32)
    if not w_prev.flags.writeable:  # one compiled signature: writeable arrays
        w_prev = w_prev.copy()
    weigh_blocks(flat, ends, w_prev, *lf_args, ux, uy, nb, float(power), fixes, loglik, scored,
                 w, res)
    start = 0
    fixed = (fixes[:, 0] != 0) | (fixes[:, 4] != 0)
    for r, (pf, ps, end, nb_r, (ev_r, ess, ok), has_fix) in enumerate(
            zip(filters, team.sets, ends.tolist(), nb.tolist(), res.tolist(), fixed.tolist(),
                strict=True)):
        scan = nb_r >= 0
        if scan or has_fix:
            if ok:
                ps.weights = w[start:end]
                ps.weights_start = start
                ps.ess_cache = (ps.weights, ess)
                ev = ev_r + float(offsets[r])
            else:  # the products underflowed: redo this filter in log space
                ps.weights, ev = _weights_in_logs(ps, w_prev[start:end],
                                                  loglik[start:end] if scan else None,
                                                  fixes[r])
                ev += float(offsets[r])
            if scan:
                evidence[r] = ev
                pf.track_evidence(ev, float(n_eff[r]))
        start = end
    return evidence


def _weights_in_logs(ps: ParticleSet, w_prev: np.ndarray, loglik: np.ndarray | None,
                     fix: np.ndarray) -> tuple[np.ndarray, float]:
    """:func:`weigh_team` for one filter in log space: normalized weights and the
    scan's log evidence (less the caller's offset; NaN without a scan)."""
    st = ps.state
    with np.errstate(divide="ignore"):
        lw = np.log(w_prev)
    log_evidence = math.nan
    if loglik is not None:
        lw = lw + loglik
        m = lw.max()
        log_evidence = float(m + np.log(np.exp(lw - m).sum()))
    if fix[0]:
        d2 = (st[0] - fix[1]) ** 2.0 + (st[1] - fix[2]) ** 2.0
        lw = lw + np.log(np.exp(fix[3] * d2) + 1e-12)
    if fix[4]:
        e = wrap_angle(st[2] - fix[5])
        lw = lw + np.log(np.exp(fix[6] * e * e) + 1e-12)
    m = lw.max()
    if not math.isfinite(m):
        raise ValueError(f"weights' log-likelihood is not finite (max {m})")
    e = np.exp(lw - m)
    e /= e.sum()
    return e, log_evidence



