"""Several robots' particle filters updated together in flat arrays.

A team of :class:`~estimators.mcl.filter.ParticleFilter` objects can be
stepped with one compiled call per operation instead of one per robot; each call
joins them in a :class:`~estimators.mcl.team.ParticleTeam` (every filter's state a
view of its flat array, reused in place by the next call):

* :func:`team_state` and :func:`team_weights`: the team's flat state and weights;
* :func:`compose_odometry_batch` composes every robot's odometry sub-steps at once;
* :func:`predict_batch` moves every robot's particles (each filter draws its
  noise from its own generator; the result equals
  :meth:`ParticleFilter.predict_delta` robot by robot, bit for bit);
* :func:`update_beam_batch` weights all robots' particles by their scans with
  one lookup in the shared :class:`~estimators.mcl.beam_table.RangeTable` and
  :class:`~estimators.mcl.beam_table.BeamLUT` (the result equals calling
  :meth:`ParticleFilter.update_beam` robot by robot, bit for bit);
* :func:`weigh_batch` weights all robots' particles by their likelihood-field
  laser scans and their DGPS / compass fixes in one pass;
* :func:`belief_summaries` computes every robot's mean, covariance and
  :meth:`ParticleFilter.belief_features` embedding with segment reductions.

Each filter keeps its own state, weights and random generator, so the
per-robot API stays valid between batched calls.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from estimators.mcl._kernels import summary_features, weighted_distances
from estimators.mcl._team_kernels import FIX_COLUMNS, compose_rows, lf_scan_rows, predict_blocks
from estimators.mcl.beam_table import scan_loglik
from estimators.mcl.likelihood_field import LF_POWER, beam_units
from estimators.mcl.sampling import standard_normals
from estimators.mcl.team import ParticleTeam, TeamMember
from estimators.mcl.weighting import weigh_team

__all__ = [
    "belief_summaries", "compose_odometry_batch", "particle_spreads", "predict_batch",
    "team_state", "team_weights", "update_beam_batch", "weigh_batch",
]


def team_state(filters: Sequence[TeamMember]) -> tuple[np.ndarray, np.ndarray]:
    """The filters' states in one flat float32 array (block layout, see
    :mod:`estimators.mcl.team`) and the particle segments' ends ``(R,)``
    (:meth:`ParticleTeam.gather`: each filter's state is made a view of the array)."""
    team = ParticleTeam.gather(filters)
    return team.state, team.ends


def team_weights(filters: Sequence[TeamMember]) -> np.ndarray:
    """The filters' weights in one ``(N,)`` array (:meth:`ParticleTeam.weights`: a view
    of the last :func:`weigh_batch`'s output when no filter changed its weights since)."""
    return ParticleTeam(filters, np.zeros(0, dtype=np.float32), np.zeros(0, dtype=np.intp)
                        ).weights()


def predict_batch(filters: Sequence[TeamMember], deltas: np.ndarray) -> None:
    """:meth:`ParticleFilter.predict_delta` of every filter with its row of ``deltas (R, 3)``,
    in one compiled pass (each filter draws its noise from its own generator)."""
    deltas = np.asarray(deltas, dtype=float)
    if deltas.shape != (len(filters), 3) or not np.all(np.isfinite(deltas)):
        raise ValueError(f"deltas must be ({len(filters)}, 3) finite, got {deltas}")
    if not filters:
        return
    team = ParticleTeam.gather(filters)
    flat, ends = team.state, team.ends
    z = np.empty(flat.size, dtype=np.float32)
    rows = []
    start = 0
    for pf, d, end in zip(filters, deltas.tolist(), ends.tolist(), strict=True):
        rows.append(pf.motion_draw(*d))
        standard_normals(pf.rng, z[3 * start:3 * end])
        start = end
    predict_blocks(flat, z, np.array(rows, dtype=np.float32), ends)
    for ps in team.sets:
        ps.after_motion()


def weigh_batch(
    filters: Sequence[TeamMember],
    ranges: np.ndarray | None,
    angles: np.ndarray | None,
    max_range: float | None,
    fixes: np.ndarray,
) -> np.ndarray:
    """Weight every filter by its likelihood-field laser scan and its fixes in one pass.

    ``ranges (R, B)``: robot ``r``'s readings at robot-frame ``angles (B,)``; a row of
    NaN is no scan (the filter is not weighted by a scan), other non-finite readings
    or readings at or beyond ``max_range`` carry no endpoint. ``fixes (R, 7)``: rows
    of :meth:`ParticleFilter.fix_row` (zeros: no fix). The filters that have a scan
    must share one map and one model. Same result as
    :meth:`ParticleFilter.update_likelihood_field` then :meth:`ParticleFilter.update_fix`
    robot by robot, up to float rounding (the fixes multiply the weights before, not
    after, they are normalized). Returns the scans' log evidences (NaN: no scan).
    """
    nr = len(filters)
    fixes = np.asarray(fixes, dtype=float)
    if fixes.shape != (nr, FIX_COLUMNS):
        raise ValueError(f"fixes must have shape ({nr}, {FIX_COLUMNS}), got {fixes.shape}")
    if not nr:
        return np.zeros(0)
    team = ParticleTeam.gather(filters)
    n = int(team.ends[-1])
    w_prev = team.weights()
    if ranges is None:
        nb = np.full(nr, -1, dtype=np.intp)
        return weigh_team(team, w_prev, fixes, nb, np.empty(n), False, np.zeros(nr),
                          np.zeros(nr))
    ranges = np.asarray(ranges, dtype=float)
    angles = np.asarray(angles, dtype=float).ravel()
    if ranges.shape != (nr, angles.size):
        raise ValueError(f"ranges must have shape ({nr}, {angles.size}), got {ranges.shape}")
    if (ranges < 0).any():
        raise ValueError(f"ranges must be >= 0, got {ranges}")
    has = (ranges == ranges).any(axis=1)  # a row of NaN is no scan
    lead = None
    for pf, scan in zip(filters, has.tolist(), strict=True):
        if not scan:
            continue
        if lead is None:
            lead = pf
        elif pf.grid is not lead.grid or (pf.config is not lead.config
                                          and pf.config != lead.config):
            raise ValueError("weigh_batch needs the filters with scans to share one map "
                             "and one config")
    if lead is None:
        return weigh_batch(filters, None, None, None, fixes)
    lf = lead.lf_field(max_range)
    ux, uy, nb, k = lf_scan_rows(ranges, *beam_units(lf, angles), lf.reach, float(max_range))
    return weigh_team(team, w_prev, fixes, nb, np.empty(n), False, k * lf.lmax,
                      k * lead.config.likelihood_exponent, lead.lf_kernel_args(max_range), ux, uy,
                      float(LF_POWER))


def compose_odometry_batch(v: np.ndarray, w: np.ndarray, dt: float) -> np.ndarray:
    """Relative motions ``(R, 3)`` of ``R`` robots' odometry sub-steps ``v, w`` ``(R, K)``.

    Row ``r`` equals :func:`~estimators.mcl.filter.compose_odometry` of ``v[r], w[r]``.
    """
    v = np.asarray(v, dtype=float)
    w = np.asarray(w, dtype=float)
    if v.shape != w.shape or v.ndim != 2:
        raise ValueError(f"v and w must be (R, K) of equal shape, got {v.shape} and {w.shape}")
    if not math.isfinite(dt) or dt < 0:
        raise ValueError(f"odometry must be finite with dt >= 0, got dt={dt}")
    out = compose_rows(np.ascontiguousarray(v), np.ascontiguousarray(w), float(dt))
    if np.isnan(out[:, 0]).any():
        raise ValueError(f"odometry must be finite, got v={v}, w={w}")
    return out


def update_beam_batch(
    filters: Sequence[TeamMember],
    ranges: np.ndarray,
    angles: np.ndarray,
    max_range: float,
    cone_half_width: float = 0.0,
) -> np.ndarray:
    """Beam-model update of every filter from its scan; returns the log evidences ``(R,)``.

    ``ranges`` ``(R, B)`` holds robot ``r``'s readings at robot-frame ``angles``
    ``(B,)``; a non-finite reading is no reading (that beam is skipped for that
    robot). The filters must share one map and one model with
    ``beam_lookup_bins`` > 0. Same result as ``filters[r].update_beam`` with
    the finite readings of row ``r``.
    """
    if not filters:
        return np.zeros(0)
    pf0 = filters[0]
    cfg = pf0.config
    if not cfg.beam_lookup_bins:
        raise ValueError("update_beam_batch needs MCLConfig.beam_lookup_bins > 0")
    for pf in filters[1:]:
        if pf.grid is not pf0.grid or (pf.config is not cfg and pf.config != cfg):
            raise ValueError("update_beam_batch needs filters sharing one map and one config")
    ranges = np.asarray(ranges, dtype=float)
    angles = np.asarray(angles, dtype=float).ravel()
    if ranges.shape != (len(filters), angles.size):
        raise ValueError(f"ranges must have shape ({len(filters)}, {angles.size}), "
                         f"got {ranges.shape}")
    if not np.all(np.isfinite(angles)):
        raise ValueError(f"beam angles must be finite, got {angles}")
    if np.any(ranges < 0):
        raise ValueError(f"ranges must be >= 0, got {ranges}")
    if not (math.isfinite(max_range) and max_range > 0):
        raise ValueError(f"max_range must be a positive finite number, got {max_range}")
    if not math.isfinite(cone_half_width) or cone_half_width < 0:
        raise ValueError(f"cone_half_width must be finite and >= 0, got {cone_half_width}")
    ok = np.isfinite(ranges)
    table, lut = pf0.beam_tables(max_range, cone_half_width)
    team = ParticleTeam.gather(filters)
    rows = lut.rows(np.where(ok, ranges, np.nan))
    loglik = scan_loglik(table, lut, team.state, angles, rows, team.ends, cfg.occupied_loglik)
    n_beams = ok.sum(axis=1)
    nr = len(filters)
    return weigh_team(team, team.weights(), np.zeros((nr, FIX_COLUMNS)), n_beams, loglik, True,
                      np.zeros(nr), n_beams * cfg.likelihood_exponent)


def belief_summaries(
    filters: Sequence[TeamMember],
    hist_cells: int = 5,
    cell_size: float = 1.0,
    heading_bins: int = 8,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means ``(R, 3)``, covariances ``(R, 3, 3)`` and belief features ``(R, F)`` float32.

    Row ``r`` matches ``filters[r].mean_pose()``, ``filters[r].belief().cov`` and
    ``filters[r].belief_features(hist_cells, cell_size, heading_bins)`` up to
    floating-point summation order.
    """
    if hist_cells < 1 or heading_bins < 1:
        raise ValueError(f"hist_cells and heading_bins must be >= 1, got {hist_cells}, "
                         f"{heading_bins}")
    if not np.isfinite(cell_size) or cell_size <= 0:
        raise ValueError(f"cell_size must be positive, got {cell_size}")
    # positions relative to each filter's cell (0, 0) centre (small numbers)
    team = ParticleTeam.gather(filters)
    w = team.weights()
    bounds = np.array([pf.grid.bounds for pf in filters], dtype=float).reshape(-1, 4)
    count_frac = np.array([min(ps.n / pf.config.n_max, 1.0) if pf.config.adaptive
                           else 1.0 for pf, ps in zip(filters, team.sets, strict=True)])
    return summary_features(team.state, w, team.ends, team.origins, bounds, count_frac,
                            int(hist_cells), 1.0 / cell_size, int(heading_bins))


def particle_spreads(filters: Sequence[TeamMember], true_xy: np.ndarray) -> np.ndarray:
    """Weighted mean distances ``(R,)`` of each filter's particles from ``true_xy[r]`` ``(R, 2)``
    (:meth:`ParticleFilter.particle_spread`)."""
    true_xy = np.asarray(true_xy, dtype=float)
    if true_xy.shape != (len(filters), 2) or not np.all(np.isfinite(true_xy)):
        raise ValueError(f"true_xy must be ({len(filters)}, 2) finite, got {true_xy.shape}")
    if not filters:
        return np.zeros(0)
    team = ParticleTeam.gather(filters)
    return weighted_distances(team.state, team.weights(), team.ends, true_xy - team.origins)
