"""Reduce episode records to a report: summary statistics, JSON and a plain-text table."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from policies.episode import FIGURES, episode_figures


def summarize(episodes: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean and (population) standard deviation over episodes of each of :data:`FIGURES`."""
    if not episodes:
        raise ValueError("summarize needs at least one episode, got []")
    out = {}
    for key in FIGURES:
        vals = np.array([ep[key] for ep in episodes], dtype=float)
        out[key] = {"mean": float(np.mean(vals)), "std": float(np.std(vals))}
    return out


def report(scenario: str, policy: str, episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """The evaluation report: ``{"scenario", "policy", "episodes", "summary"}``."""
    return {
        "scenario": scenario,
        "policy": policy,
        "episodes": [episode_figures(ep) for ep in episodes],
        "summary": summarize(episodes),
    }


def write_json(data: dict[str, Any], path: str | Path) -> None:
    """Write ``data`` as JSON (NaN written as ``null``), creating parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if isinstance(x, (float, np.floating)):
            return float(x) if np.isfinite(x) else None
        if isinstance(x, np.integer):
            return int(x)
        return x

    path.write_text(json.dumps(clean(data), indent=2, allow_nan=False) + "\n")


def format_table(summary: dict[str, dict[str, float]], n_episodes: int) -> str:
    """A plain-text table of ``mean +/- std`` per figure."""
    labels = {
        "localization_error_m": "team localization error (m)",
        "coverage": "coverage (fraction)",
        "map_rmse_m": "map RMSE (m)",
        "collisions": "collisions",
        "tip_overs": "tip-overs",
    }
    width = max(len(v) for v in labels.values())
    lines = [f"{'figure':<{width}}  mean +/- std over {n_episodes} episode(s)"]
    lines.append("-" * (width + 34))
    for key in FIGURES:
        s = summary[key]
        lines.append(f"{labels[key]:<{width}}  {s['mean']:.4f} +/- {s['std']:.4f}")
    return "\n".join(lines)
