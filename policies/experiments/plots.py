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
    """The final team terrain map of one episode beside the true height field, on one
    elevation scale; unmapped cells, canopies, obstacles, steep ground and the objects the
    team marked are drawn and named in the legend. ``title`` (default: the episode's seed,
    final coverage and map RMSE) heads the figure."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle, Patch

    maps = episode["maps"]
    est, true = maps["estimated"], maps["true"]
    extent = maps["extent"]
    lo, hi = float(np.nanmin(true)), float(np.nanmax(true))
    fig = new_figure(11, 5.2)
    axes = [fig.add_subplot(1, 2, k + 1) for k in range(2)]
    names = ("team terrain map (end of the episode)", "true height field")
    for ax, grid, name in zip(axes, (est, true), names, strict=True):
        im = ax.imshow(grid.T, origin="lower", extent=extent, cmap="terrain", vmin=lo, vmax=hi)
        ax.set_title(name)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    axes[0].set_facecolor(UNMAPPED_COLOR)  # NaN cells (never measured) show the background
    key = [Patch(color=UNMAPPED_COLOR, label="unmapped (left panel)")]
    key += _draw_layout(axes, maps.get("layout"), Circle, Line2D)
    obj = maps["objects"]
    if len(obj):
        axes[0].plot(obj[:, 0], obj[:, 1], "r*", ms=10)
        key.append(Line2D([], [], marker="*", color="r", ls="", ms=10,
                          label="objects the team marked"))
    for ax in axes:  # marks near the border must not widen the view
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
    fig.colorbar(im, ax=axes, label="elevation (m), both panels", shrink=0.85)
    fig.legend(handles=key, loc="lower center", ncol=4, fontsize=8, frameon=False,
               bbox_to_anchor=(0.45, -0.02))
    rmse = episode.get("map_rmse_m", float("nan"))
    fig.suptitle(title or f"episode seed {episode.get('seed', '?')}: final coverage "
                          f"{episode.get('coverage', 0):.3f}, map RMSE {rmse:.3f} m")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path


#: The background of the terrain map where the team measured nothing.
UNMAPPED_COLOR = "0.82"
#: Colour and legend name of each round obstacle kind on the terrain plot.
LAYOUT_STYLE = {"tree": ("#1b4d1b", "tree trunk"), "rock": ("0.35", "rock"),
                "ooi": ("#d4a017", "object of interest")}


def _draw_layout(axes, layout: dict[str, Any] | None, circle, line) -> list:
    """Draw the known map's canopies, round obstacles and steep ground on both ``axes``;
    returns their legend entries."""
    if not layout:
        return []
    key = []
    if len(layout["canopy"]):
        for ax in axes:
            for x, y, r in layout["canopy"]:
                ax.add_patch(circle((x, y), r, fill=False, ls="--", lw=0.7, color="#1b4d1b",
                                    alpha=0.7))
        key.append(line([], [], ls="--", lw=0.7, color="#1b4d1b",
                        label="tree canopy (weak GPS)"))
    for kind, marks in layout["obstacles"].items():
        color, label = LAYOUT_STYLE.get(kind, ("k", kind))
        for ax in axes:
            for x, y, r in marks:
                ax.add_patch(circle((x, y), r, color=color))
        key.append(line([], [], marker="o", ls="", color=color, ms=6, label=label))
    xs, ys, steep = layout["steep"]
    if steep.any():
        for ax in axes:
            ax.contour(xs, ys, steep.astype(float), levels=[0.5], colors=["#b22222"],
                       linewidths=1.0)
        key.append(line([], [], color="#b22222", lw=1.0, label="steep ground (tips over)"))
    return key
