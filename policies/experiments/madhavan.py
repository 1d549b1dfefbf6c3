"""The DGPS-outage experiment (Madhavan, Fregene, Parker, Fig. 4(b)) as a library function.

:func:`run_dgps_outage` drives the two robots of the ``dgps_outage`` scenario
straight east (heading held on each robot's own estimate), records the
position standard deviation of every robot's EKF, the DGPS fixes and the
laser-based cooperative updates, and extracts the three figures the paper's
plot shows for the robot that loses DGPS. :func:`plot_dgps_outage` draws the
figure.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

import coop_loc_env
from coop_loc_env.scenarios.madhavan import LANE_SPEED
from estimators.geometry import wrap_angle

OUTAGE_ROBOT = 1


def _gps_steps(n_steps: int, dt: float, rate: float) -> np.ndarray:
    """Whether the DGPS receiver reports on each env step (same schedule as the sensors)."""
    k = np.arange(n_steps)
    return np.floor((k + 1) * dt * rate + 1e-9) > np.floor(k * dt * rate + 1e-9)


def _longest_outage(gps_step: np.ndarray, fix: np.ndarray) -> tuple[int, int]:
    """Steps ``(first missed fix, first fix after it)`` of the longest run of missed fixes.

    A brief dropout at the canopy's edge is not the outage; the longest run is.
    """
    report = np.flatnonzero(gps_step)
    missed = ~fix[report]
    if not missed.any():
        raise ValueError("robot 1 never lost DGPS: check the scenario's canopy and lanes")
    best, best_len, k = 0, 0, 0
    while k < len(report):
        if missed[k]:
            j = k
            while j < len(report) and missed[j]:
                j += 1
            if j - k > best_len:
                best, best_len = k, j - k
            k = j
        else:
            k += 1
    start = int(report[best])
    after = best + best_len
    end = int(report[after]) if after < len(report) else len(gps_step) - 1
    return start, end


def position_std(cov: np.ndarray) -> np.ndarray:
    """RMS per-axis position standard deviation ``sqrt((P_xx + P_yy) / 2)`` of ``(..., 3, 3)``."""
    return np.sqrt(0.5 * (cov[..., 0, 0] + cov[..., 1, 1]))


def run_dgps_outage(seed: int = 0, duration_s: float = 50.0, **overrides: Any) -> dict[str, Any]:
    """Run the experiment once.

    Args:
        seed: episode seed.
        duration_s: how long to drive (s).
        **overrides: config overrides of the ``dgps_outage`` scenario.

    Returns:
        ``std_before_outage_m`` (robot 1's position std at the last step
        before the outage, the longest run of missed DGPS fixes),
        ``std_peak_m`` (its largest std during the outage),
        ``std_after_first_coop_update_m`` (its std right after the first
        cooperative update inside the outage; NaN if none),
        the outage interval ``outage_s`` ``(start, end)``, the times of the
        cooperative updates ``coop_update_times_s`` and the per-step series
        ``time_s``, ``std_m`` ``(T, 2)``, ``error_m`` ``(T, 2)``, ``gps_fix`` ``(T, 2)``.
    """
    if "max_cycles" not in overrides:  # the episode lasts as long as asked
        dt = coop_loc_env.make_config("dgps_outage", **overrides).dt
        overrides["max_cycles"] = max(1, int(round(duration_s / dt)))
    env = coop_loc_env.parallel_env("dgps_outage", **overrides)
    cfg = env.config
    n_steps = int(round(duration_s / cfg.dt))
    if n_steps > cfg.max_cycles:
        raise ValueError(
            f"duration_s={duration_s} needs {n_steps} steps but max_cycles={cfg.max_cycles}: "
            f"leave max_cycles out, or set it to at least {n_steps}"
        )
    env.reset(seed=seed)
    v = LANE_SPEED / cfg.max_speed
    std, err, fix, coop = [], [], [], []
    for _ in range(n_steps):
        est = env.estimated_poses
        actions = {
            a: np.array([v, np.clip(-2.0 * wrap_angle(est[env.agent_name_mapping[a], 2]), -1, 1)])
            for a in env.agents
        }
        _, _, _, _, infos = env.step(actions)
        std.append(position_std(env.estimated_covariances))
        err.append([infos[a]["position_error"] for a in env.possible_agents])
        fix.append([infos[a]["gps_fix"] for a in env.possible_agents])
        det = env.last_readings.detections
        pair = {OUTAGE_ROBOT} & (set(det.observer.tolist()) | set(det.target.tolist()))
        coop.append(bool(len(det)) and bool(pair))
    env.close()
    std, err, fix, coop = np.array(std), np.array(err), np.array(fix), np.array(coop)
    t = (np.arange(n_steps) + 1) * cfg.dt
    gps_step = _gps_steps(n_steps, cfg.dt, cfg.gps_rate)
    r = OUTAGE_ROBOT
    start, end = _longest_outage(gps_step, fix[:, r])
    s = std[:, r]
    coop_steps = np.flatnonzero(coop)
    inside = coop_steps[(coop_steps > start) & (coop_steps <= end)]
    drops = [k for k in inside if s[k] < s[k - 1]]
    after = float(s[drops[0]]) if drops else float("nan")
    return {
        "std_before_outage_m": float(s[start - 1]) if start > 0 else float(s[0]),
        "std_peak_m": float(s[start : end + 1].max()),
        "std_after_first_coop_update_m": after,
        "outage_s": (float(t[start]), float(t[end])),
        "coop_update_times_s": [float(t[k]) for k in coop_steps],
        "time_s": t,
        "std_m": std,
        "error_m": err,
        "gps_fix": fix,
    }


def plot_dgps_outage(result: dict[str, Any], path: str | Path) -> Path:
    """A plot like the paper's Fig. 4(b): position std vs time, outage shaded, updates marked."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 4.2), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    t = result["time_s"]
    a, b = result["outage_s"]
    ax.axvspan(a, b, color="0.85", label="robot 1: no DGPS (under canopy)")
    for k, tc in enumerate(result["coop_update_times_s"]):
        ax.axvline(tc, color="tab:red", lw=0.8, ls="--",
                   label="laser-based cooperative update" if k == 0 else None)
    ax.plot(t, result["std_m"][:, 1], color="tab:blue", lw=1.6, label="robot 1 position std")
    ax.plot(t, result["std_m"][:, 0], color="tab:green", lw=1.0, label="robot 0 position std")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position standard deviation (m)")
    ax.set_title("DGPS outage and laser-based cooperative localization (cf. Madhavan et al. "
                 "Fig. 4(b))", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path
