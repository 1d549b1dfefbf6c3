"""Time-to-localize figures of a comparison report (:func:`~policies.experiments.compare.compare`).

* :func:`median_ci`: the median of per-episode values with a bootstrap interval;
* :func:`localized_curve`: the fraction of robots localized (first time their
  spread fell below the threshold) by each time, over all episodes of a policy;
* :func:`gap_closed`: how much of the distance from a baseline to a reference
  (e.g. an oracle that knows the truth) a policy covers, ``(B - L) / (B - R)``;
* :func:`plot_localized_curve`: one curve per policy of a report.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def median_ci(values, level: float = 0.95, n_boot: int = 2000, seed: int = 0
              ) -> tuple[float, float, float]:
    """``(median, low, high)``: the median and its percentile-bootstrap ``level`` interval."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return float("nan"), float("nan"), float("nan")
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    rng = np.random.default_rng(seed)
    boots = np.median(v[rng.integers(0, len(v), (n_boot, len(v)))], axis=1)
    tail = (1 - level) / 2
    return float(np.median(v)), float(np.quantile(boots, tail)), float(np.quantile(boots, 1 - tail))


def localized_curve(records: list[dict[str, Any]], times: np.ndarray) -> np.ndarray:
    """Fraction of all robots of ``records`` (episode records of one policy, with
    ``robot_times_to_localize_s`` and ``robot_localized``) localized at or before each time."""
    t = np.concatenate([np.asarray(r["robot_times_to_localize_s"], dtype=float) for r in records])
    done = np.concatenate([np.asarray(r["robot_localized"], dtype=bool) for r in records])
    times = np.asarray(times, dtype=float)
    return ((t[None, :] <= times[:, None]) & done[None, :]).mean(axis=1)


def gap_closed(baseline: float, policy: float, reference: float) -> float:
    """``(baseline - policy) / (baseline - reference)``: 0 at the baseline, 1 at the reference."""
    if baseline == reference:
        raise ValueError(f"baseline and reference are equal ({baseline!r}): no gap to close")
    return (baseline - policy) / (baseline - reference)


def plot_localized_curve(report: dict[str, Any], path: str | Path, dt: float) -> Path:
    """The fraction of robots localized over time, one line per policy of ``report``."""
    from policies.experiments.compare import policy_label
    from policies.experiments.plots import new_figure

    episodes = report["episodes"]
    horizon = max(max(r["steps"] for r in recs) for recs in episodes.values()) * dt
    times = np.arange(0.0, horizon + dt / 2, dt)
    fig = new_figure(6.5, 4)
    ax = fig.add_subplot(1, 1, 1)
    for spec in report["policies"]:
        ax.plot(times, localized_curve(episodes[spec], times), lw=1.5, label=policy_label(spec))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("fraction of robots localized")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"{report['scenario']}: {report['n_episodes']} episodes per policy "
                 f"(seeds {report['seed']}..{report['seed'] + report['n_episodes'] - 1})",
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight", dpi=120)
    return path
