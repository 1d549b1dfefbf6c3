"""The experiments of Howard, Mataric and Sukhatme as a library: the runners.

The behaviours they drive are scripted controllers:
:class:`~policies.scripted.dispersal.DispersalPolicy` spreads a crowded team
through a building by each robot's own sensors, and
:class:`~policies.scripted.circuit.CircuitPolicy` drives one robot around the
``circuit`` loop past six stationary ones.

* :func:`run_dispersal` and :func:`run_circuit` run the scenarios with the
  centralized MLE and record the team's Eq. 15 relative errors over time;
  :func:`plot_howard` draws both curves.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import coop_loc_env
from coop_loc_env.scenarios.howard import DRIVER
from estimators.relative_metrics import relative_errors
from policies.scripted.circuit import CircuitPolicy
from policies.scripted.dispersal import DispersalPolicy

Progress = Callable[[int], None]


def _run(env, policy, n_steps: int, seed: int, progress: Progress | None) -> dict[str, Any]:
    """Run ``n_steps`` steps; records the team's Eq. 15 errors and the detections."""
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    errors, spread, pairs = [], [], []
    for _ in range(n_steps):
        if not env.agents:
            break
        obs, *_ = env.step(policy.act(obs))
        errors.append(relative_errors(env.estimated_poses, env.world.poses))
        xy = env.world.poses[:, :2]
        d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        spread.append(float(d[np.isfinite(d)].mean()))
        det = env.last_readings.detections
        pairs.append(set(zip(det.observer.tolist(), det.target.tolist(), strict=True)))
        if progress is not None:
            progress(1)
    errors = np.array(errors)
    t = (np.arange(len(errors)) + 1) * env.config.dt
    return {"times_s": t, "errors": errors, "mean_distance_m": np.array(spread), "pairs": pairs}


def run_dispersal(
    seed: int = 0, duration_s: float = 120.0, progress: Progress | None = None, **overrides: Any
) -> dict[str, Any]:
    """Run ``dispersal`` with :class:`DispersalPolicy` and the centralized MLE.

    Returns ``times_s`` ``(T,)``, ``range_error_m``, ``bearing_error_rad``,
    ``orientation_error_rad`` (team means over ordered pairs, Eq. 15) and
    ``mean_distance_m`` (true distance between robots, mean over pairs:
    how far the team has spread), plus ``detections`` per step.
    """
    overrides.setdefault("estimator", "mle")
    n_steps = _steps(duration_s, coop_loc_env.make_config("dispersal", **overrides))  # fail early
    env = coop_loc_env.parallel_env("dispersal", **overrides)
    rec = _run(env, DispersalPolicy(), n_steps, seed, progress)
    env.close()
    e = rec["errors"]
    return {
        "times_s": rec["times_s"],
        "range_error_m": e[:, 0],
        "bearing_error_rad": e[:, 1],
        "orientation_error_rad": e[:, 2],
        "mean_distance_m": rec["mean_distance_m"],
        "detections": np.array([len(p) for p in rec["pairs"]]),
    }


def run_circuit(
    seed: int = 0, duration_s: float = 175.0, progress: Progress | None = None,
    after_s: float = 2.0, **overrides: Any
) -> dict[str, Any]:
    """Run ``circuit`` with :class:`CircuitPolicy` and the centralized MLE.

    Returns the series of :func:`run_dispersal` (without ``detections``), the
    times the driver and a stationary robot first saw each other
    (``sightings_s``: robot -> time), ``closure_time_s`` (the first sighting of
    robot 0 after the driver has been out of its sight for more than 30 s; NaN
    if the loop was not closed), ``error_before_closure_m`` (team range error at
    the last step before it) and ``error_after_closure_m`` (``after_s`` seconds
    after it, once the closing observation is optimized in).
    """
    overrides.setdefault("estimator", "mle")
    n_steps = _steps(duration_s, coop_loc_env.make_config("circuit", **overrides))  # fail early
    env = coop_loc_env.parallel_env("circuit", **overrides)
    rec = _run(env, CircuitPolicy(), n_steps, seed, progress)
    env.close()
    t, e = rec["times_s"], rec["errors"]
    seen_steps: dict[int, list[int]] = {}
    for k, pairs in enumerate(rec["pairs"]):
        for a, b in pairs:
            if DRIVER in (a, b):
                seen_steps.setdefault(b if a == DRIVER else a, []).append(k)
    sightings = {int(r): float(t[ks[0]]) for r, ks in sorted(seen_steps.items())}
    closure = float("nan")
    steps0 = np.asarray(seen_steps.get(0, []))
    gaps = np.flatnonzero(np.diff(steps0) * env.config.dt > 30.0)
    before = after = float("nan")
    if len(gaps):
        k = int(steps0[gaps[0] + 1])
        closure = float(t[k])
        before = float(e[k - 1, 0])
        k_after = min(k + int(round(after_s / env.config.dt)), len(t) - 1)
        after = float(e[k_after, 0])
    return {
        "times_s": t,
        "range_error_m": e[:, 0],
        "bearing_error_rad": e[:, 1],
        "orientation_error_rad": e[:, 2],
        "sightings_s": sightings,
        "closure_time_s": closure,
        "error_before_closure_m": before,
        "error_after_closure_m": after,
    }


def _steps(duration_s: float, cfg) -> int:
    n_steps = int(round(duration_s / cfg.dt))
    if not 1 <= n_steps <= cfg.max_cycles:
        hint = f" (raise it: --set max_cycles={n_steps})" if n_steps > cfg.max_cycles else ""
        raise ValueError(
            f"duration_s={duration_s!r} needs {n_steps} steps; allowed 1..max_cycles="
            f"{cfg.max_cycles}{hint}"
        )
    return n_steps


def plot_howard(dispersal: dict[str, Any] | None, circuit: dict[str, Any] | None,
                path: str | Path) -> Path:
    """Range error vs time for both experiments (cf. Howard et al.'s figures)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    panels = [(k, r) for k, r in (("dispersal", dispersal), ("circuit", circuit)) if r]
    fig = Figure(figsize=(7.0 * max(len(panels), 1), 4.2), dpi=100)
    FigureCanvasAgg(fig)
    for j, (name, res) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), j + 1)
        ax.plot(res["times_s"], res["range_error_m"], color="tab:blue", lw=1.4,
                label="mean relative range error")
        if name == "dispersal":
            ax2 = ax.twinx()
            ax2.plot(res["times_s"], res["mean_distance_m"], color="tab:gray", lw=1.0,
                     ls="--", label="mean distance between robots")
            ax2.set_ylabel("mean distance between robots (m)", color="tab:gray")
            ax.set_title("dispersal: 20 robots spread out of one room", fontsize=10)
            handles = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
            ax.legend(handles=handles, loc="upper left", fontsize=8)
        else:
            for k, (robot, ts) in enumerate(res["sightings_s"].items()):
                ax.axvline(ts, color="tab:green", lw=0.8, ls=":",
                           label="first sighting of robot (number)" if k == 0 else None)
                ax.annotate(str(robot), (ts, 0.0), xycoords=("data", "axes fraction"),
                            xytext=(2, 3), textcoords="offset points", fontsize=8,
                            color="tab:green")
            if np.isfinite(res["closure_time_s"]):
                ax.axvline(res["closure_time_s"], color="tab:red", lw=1.2, ls="--",
                           label="loop closure (robot 0 seen again)")
            ax.set_title("circuit: one robot drives past six stationary ones", fontsize=10)
            ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("mean relative range error (m)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path
