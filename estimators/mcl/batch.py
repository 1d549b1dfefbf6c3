"""Several robots' particle filters updated together in flat arrays.

A team of :class:`~estimators.mcl.filter.ParticleFilter` objects can be
stepped with one compiled call per operation instead of one per robot:

* :func:`team_state` gathers the filters' states into one flat array (each
  filter's state becomes a view of it, so later team calls reuse it as long as
  no filter replaced its state);
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
from estimators.mcl.filter import ParticleFilter
from estimators.mcl.likelihood_field import LF_POWER, beam_units
from estimators.mcl.sampling import standard_normals
from estimators.mcl.weighting import weigh_filters

__all__ = [
    "belief_summaries", "compose_odometry_batch", "particle_spreads", "predict_batch",
    "team_state", "team_weights", "update_beam_batch", "weigh_batch",
]


_ENDS: dict[tuple[int, ...], np.ndarray] = {}  # segment ends by particle counts (not written)


def team_state(filters: Sequence[ParticleFilter]) -> tuple[np.ndarray, np.ndarray]:
    """The filters' states in one flat float32 array (block layout, see
    :mod:`estimators.mcl._team_kernels`) and the particle segments' ends ``(R,)``.

    Each filter's state is made a view of the array, so a later call finds it
    in place (no copy) unless a filter replaced its state meanwhile.
    """
    if not filters:
        return np.zeros(0, dtype=np.float32), np.zeros(0, dtype=np.intp)
    flat = filters[0]._state.base
    valid = flat is not None
    counts = []
    start = 0
    for pf in filters:
        n = pf._weights.size
        counts.append(n)
        if valid and (pf._state.base is not flat or pf._block_start != start):
            valid = False
        start += n
    key = tuple(counts)
    ends = _ENDS.get(key)
    if ends is None:
        if len(_ENDS) > 256:  # adaptive counts vary: keep the cache small
            _ENDS.clear()
        ends = _ENDS[key] = np.cumsum(np.array(counts, dtype=np.intp))
    if valid and flat.size == 3 * start:
        return flat, ends
    flat = np.concatenate([pf._flat_state() for pf in filters])
    start = 0
    for pf, n in zip(filters, counts, strict=True):
        pf._state = flat[3 * start:3 * (start + n)].reshape(3, n)
        pf._block_start = start
        start += n
    return flat, ends


def team_weights(filters: Sequence[ParticleFilter]) -> np.ndarray:
    """The filters' weights in one ``(N,)`` array (a view of the last
    :func:`weigh_batch`'s output when no filter changed its weights since)."""
    if not filters:
        return np.zeros(0)
    w = filters[0]._weights.base
    start = 0
    for pf in filters:
        if w is None or pf._weights.base is not w or pf._wblock_start != start:
            break
        start += pf._weights.size
    else:
        if w.size == start:
            return w
    return np.concatenate([pf._weights for pf in filters])


def predict_batch(filters: Sequence[ParticleFilter], deltas: np.ndarray) -> None:
    """:meth:`ParticleFilter.predict_delta` of every filter with its row of ``deltas (R, 3)``,
    in one compiled pass (each filter draws its noise from its own generator)."""
    deltas = np.asarray(deltas, dtype=float)
    if deltas.shape != (len(filters), 3) or not np.all(np.isfinite(deltas)):
        raise ValueError(f"deltas must be ({len(filters)}, 3) finite, got {deltas}")
    if not filters:
        return
    flat, ends = team_state(filters)
    z = np.empty(flat.size, dtype=np.float32)
    rows = []
    start = 0
    for pf, d, end in zip(filters, deltas.tolist(), ends.tolist(), strict=True):
        rows.append(pf._motion_draw(*d))
        standard_normals(pf.rng, z[3 * start:3 * end])
        start = end
    predict_blocks(flat, z, np.array(rows, dtype=np.float32), ends)
    for pf in filters:
        pf._after_motion()


def weigh_batch(
    filters: Sequence[ParticleFilter],
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
    flat, ends = team_state(filters)
    n = int(ends[-1])
    w_prev = team_weights(filters)
    if ranges is None:
        nb = np.full(nr, -1, dtype=np.intp)
        return weigh_filters(filters, flat, ends, w_prev, fixes, nb, np.empty(n), False,
                             np.zeros(nr), np.zeros(nr))
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
    lf = lead._lf_field(max_range)
    ux, uy, nb, k = lf_scan_rows(ranges, *beam_units(lf, angles), lf.reach, float(max_range))
    return weigh_filters(filters, flat, ends, w_prev, fixes, nb, np.empty(n), False,
                         k * lf.lmax, k * lead.config.likelihood_exponent,
                         lead.lf_kernel_args(max_range), ux, uy, float(LF_POWER))


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
    filters: Sequence[ParticleFilter],
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
    flat, ends = team_state(filters)
    rows = lut.rows(np.where(ok, ranges, np.nan))
    loglik = scan_loglik(table, lut, flat, angles, rows, ends, cfg.occupied_loglik)
    n_beams = ok.sum(axis=1)
    nr = len(filters)
    return weigh_filters(filters, flat, ends, team_weights(filters), np.zeros((nr, FIX_COLUMNS)),
                         n_beams, loglik, True, np.zeros(nr), n_beams * cfg.likelihood_exponent)


def belief_summaries(
    filters: Sequence[ParticleFilter],
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
    flat, ends = team_state(filters)
    w = team_weights(filters)
    org = np.array([pf._org_xy for pf in filters]).reshape(-1, 2)
    bounds = np.array([pf.grid.bounds for pf in filters], dtype=float).reshape(-1, 4)
    count_frac = np.array([min(pf._weights.size / pf.config.n_max, 1.0) if pf.config.adaptive
                           else 1.0 for pf in filters])
    return summary_features(flat, w, ends, org, bounds, count_frac, int(hist_cells),
                            1.0 / cell_size, int(heading_bins))


def particle_spreads(filters: Sequence[ParticleFilter], true_xy: np.ndarray) -> np.ndarray:
    """Weighted mean distances ``(R,)`` of each filter's particles from ``true_xy[r]`` ``(R, 2)``
    (:meth:`ParticleFilter.particle_spread`)."""
    true_xy = np.asarray(true_xy, dtype=float)
    if true_xy.shape != (len(filters), 2) or not np.all(np.isfinite(true_xy)):
        raise ValueError(f"true_xy must be ({len(filters)}, 2) finite, got {true_xy.shape}")
    if not filters:
        return np.zeros(0)
    flat, ends = team_state(filters)
    w = team_weights(filters)
    org = np.array([pf._org_xy for pf in filters])
    return weighted_distances(flat, w, ends, true_xy - org)
