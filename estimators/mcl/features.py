"""Fixed-size belief embedding of a particle set, for learning.

:func:`belief_feature_names` gives the layout; :func:`belief_features` computes it
from a weighted particle set (:meth:`ParticleFilter.belief_features
<estimators.mcl.filter.ParticleFilter.belief_features>` passes its own).
"""

from __future__ import annotations

import numpy as np

from estimators.geometry import wrap_angle

__all__ = ["belief_feature_names", "belief_features", "check_feature_args"]


def belief_feature_names(hist_cells: int = 5, heading_bins: int = 8) -> list[str]:
    """Names of the entries of :meth:`ParticleFilter.belief_features`, in order.

    Layout (``K = hist_cells``, ``H = heading_bins``; lengths in brackets)::

        x_norm, y_norm                      [2]  weighted mean mapped to [-1, 1] over the
                                                  map's bounds
        cos_heading, sin_heading            [2]  cos, sin of the circular-mean heading
        log10_std_x, log10_std_y            [2]  log10 of the weighted std (m), clipped
                                                  to [-3, 2]
        log10_std_heading                   [1]  log10 of the circular std (rad), same clip
        rho_xy, rho_xheading, rho_yheading  [3]  weighted correlations
        heading_resultant                   [1]  mean resultant length in [0, 1]
        ess_fraction                        [1]  effective sample size / N
        hist_entropy                        [1]  entropy of the histogram below / log(K*K+1)
        count_fraction                      [1]  N / n_max (1 when not adaptive)
        hist_r{i}_c{j}                      [K*K] particle mass in an egocentric K x K
                                                  grid centred on the mean pose, rows
                                                  along the mean heading (forward,
                                                  i = 0 is farthest behind), columns
                                                  to the left (j = 0 is rightmost)
        hist_outside                        [1]  mass outside that grid
        heading_hist_{h}                    [H]  mass of (heading - mean heading) in H
                                                  equal bins starting at -pi

    Total length ``14 + K*K + 1 + H``; the histogram entries plus
    ``hist_outside`` sum to 1, as do the heading bins. The first ten entries
    have the same meaning and scaling as the env's Gaussian-belief features.
    """
    if hist_cells < 1 or heading_bins < 1:
        raise ValueError(f"hist_cells and heading_bins must be >= 1, got {hist_cells}, "
                         f"{heading_bins}")
    names = [
        "x_norm", "y_norm", "cos_heading", "sin_heading", "log10_std_x", "log10_std_y",
        "log10_std_heading", "rho_xy", "rho_xheading", "rho_yheading", "heading_resultant",
        "ess_fraction", "hist_entropy", "count_fraction",
    ]
    names += [f"hist_r{i}_c{j}" for i in range(hist_cells) for j in range(hist_cells)]
    names.append("hist_outside")
    names += [f"heading_hist_{h}" for h in range(heading_bins)]
    return names


def check_feature_args(hist_cells: int, cell_size: float, heading_bins: int) -> None:
    """Raise ``ValueError`` for a histogram layout :func:`belief_features` cannot build."""
    belief_feature_names(hist_cells, heading_bins)
    if not np.isfinite(cell_size) or cell_size <= 0:
        raise ValueError(f"cell_size must be positive, got {cell_size}")


def belief_features(
    w: np.ndarray,
    st: np.ndarray,
    mean: np.ndarray,
    ess_fraction: float,
    count_fraction: float,
    bounds: tuple[float, float, float, float],
    hist_cells: int = 5,
    cell_size: float = 1.0,
    heading_bins: int = 8,
) -> np.ndarray:
    """Fixed-size ``float32`` embedding of a belief; layout in :func:`belief_feature_names`.

    ``w`` ``(N,)`` are normalized weights, ``st`` ``(3, N)`` world poses and
    ``mean`` their weighted mean pose with the circular mean heading;
    ``ess_fraction`` is the effective sample size over ``N`` and
    ``count_fraction`` the particle count over its cap (clipped to 1);
    ``bounds`` ``(xmin, ymin, xmax, ymax)`` scale the mean to ``[-1, 1]``.
    The egocentric histogram is a ``hist_cells x hist_cells`` grid of
    ``cell_size`` m cells centred on the mean pose and aligned with the mean
    heading. The length does not depend on the particle count.
    """
    check_feature_args(hist_cells, cell_size, heading_bins)
    resultant = float(np.hypot(np.dot(w, np.cos(st[2])), np.dot(w, np.sin(st[2]))))
    d = st - mean[:, None]
    d[2] = wrap_angle(d[2])
    cov = (d * w) @ d.T
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    denom = np.outer(std, std)
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = np.where(denom > 0, cov / np.where(denom > 0, denom, 1.0), 0.0)
    # float32 headings can give a resultant a hair above 1: clamp, or the log turns
    # positive and the square root NaN.
    circ_std = np.sqrt(-2.0 * np.log(min(max(resultant, 1e-300), 1.0)))
    # egocentric histogram
    c, s = np.cos(mean[2]), np.sin(mean[2])
    fwd = c * d[0] + s * d[1]
    left = -s * d[0] + c * d[1]
    half = hist_cells * cell_size / 2.0
    row = np.floor((fwd + half) / cell_size).astype(np.intp)
    col = np.floor((half - left) / cell_size).astype(np.intp)
    inside = (row >= 0) & (row < hist_cells) & (col >= 0) & (col < hist_cells)
    hist = np.bincount(
        row[inside] * hist_cells + col[inside], weights=w[inside],
        minlength=hist_cells * hist_cells,
    )
    outside = max(0.0, 1.0 - float(hist.sum()))
    mass = np.append(hist, outside)
    nz = mass[mass > 0]
    entropy = float(-(nz * np.log(nz)).sum() / np.log(mass.size)) if mass.size > 1 else 0.0
    hb = np.floor((d[2] + np.pi) / (2 * np.pi) * heading_bins).astype(np.intp)
    hhist = np.bincount(np.clip(hb, 0, heading_bins - 1), weights=w, minlength=heading_bins)
    xmin, ymin, xmax, ymax = bounds
    log_std = np.clip(np.log10(np.maximum([std[0], std[1], circ_std], 1e-12)), -3.0, 2.0)
    feats = np.concatenate([
        [(mean[0] - xmin) / (xmax - xmin) * 2 - 1, (mean[1] - ymin) / (ymax - ymin) * 2 - 1,
         c, s, *log_std, *np.clip([corr[0, 1], corr[0, 2], corr[1, 2]], -1.0, 1.0), resultant,
         ess_fraction, entropy, min(count_fraction, 1.0)],
        hist, [outside], hhist,
    ]).astype(np.float32)
    assert feats.size == len(belief_feature_names(hist_cells, heading_bins))
    return feats
