"""Evaluation plots (matplotlib, Agg): error vs time per robot, final map vs true terrain."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def new_figure(width: float, height: float):
    """A matplotlib figure on an Agg canvas (no display needed)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def plot_errors(episodes: list[dict[str, Any]], path: str | Path, title: str = "") -> Path:
    """Localization error vs time, one line per robot (first episode solid, the others faint,
    both named in the legend)."""
    fig = new_figure(8, 4)
    ax = fig.add_subplot(1, 1, 1)
    colors = [f"C{i}" for i in range(10)]
    for k, ep in enumerate(episodes):
        t = ep["series"]["time_s"]
        err = ep["series"]["position_error_m"]
        for i in range(err.shape[1]):
            ax.plot(t, err[:, i], color=colors[i % 10], lw=1.2 if k == 0 else 0.6,
                    alpha=1.0 if k == 0 else 0.35,
                    label=f"robot_{i} (seed {ep['seed']})" if k == 0 else None)
    if len(episodes) > 1:  # name the faint lines once
        seeds = [ep["seed"] for ep in episodes[1:]]
        ax.plot([], [], color="0.5", lw=0.6, alpha=0.5,
                label=f"other episodes (seed{'s' if len(seeds) > 1 else ''} "
                      f"{', '.join(map(str, seeds))}), same colours")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position error (m)")
    ax.set_title(title or "localization error per robot")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path


def plot_terrain(episode: dict[str, Any], path: str | Path, title: str = "") -> Path:
    """The final team terrain map (measured cells; objects marked) beside the true height field."""
    maps = episode["maps"]
    est, true = maps["estimated"], maps["true"]
    extent = maps["extent"]
    lo, hi = float(np.nanmin(true)), float(np.nanmax(true))
    fig = new_figure(11, 4.8)
    axes = [fig.add_subplot(1, 2, k + 1) for k in range(2)]
    for ax, grid, name in zip(axes, (est, true), ("team terrain map", "true height field"),
                              strict=True):
        im = ax.imshow(grid.T, origin="lower", extent=extent, cmap="terrain", vmin=lo, vmax=hi)
        ax.set_title(name)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    obj = maps["objects"]
    if len(obj):
        axes[0].plot(obj[:, 0], obj[:, 1], "r*", ms=10, label="objects marked")
        axes[0].legend(loc="upper right", fontsize=8)
    fig.colorbar(im, ax=axes, label="elevation (m)", shrink=0.85)
    rmse = episode.get("map_rmse_m", float("nan"))
    fig.suptitle(title or f"coverage {episode.get('coverage', 0):.3f}, map RMSE {rmse:.3f} m")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path
