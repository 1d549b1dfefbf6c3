"""The collaborative-MCL experiments of Fox, Burgard, Kruppa and Thrun as a library.

* :func:`run_fox_episode` runs one episode of ``symmetric_hallway`` or
  ``hexagon`` with or without robot detections and records each robot's
  ``particle_spread`` (the paper's error: mean distance of the particles from
  the true pose) over time, the robots driven by
  :class:`~policies.scripted.wander.WanderPolicy` (forward and away from
  obstacles by each robot's own range readings).
* :func:`robot_times_to_localize` finds when each robot first brings its spread
  below 1.5 m (the paper's "localized").
* :func:`run_hallway_experiment` / :func:`run_hexagon_experiment` repeat the
  episodes over seeds in both conditions and reduce them to the figures
  ``scripts/reproduce_fox.py`` prints; :func:`plot_error_vs_time` draws the
  error-vs-time figure (the paper's Figs. 12(b) and 14).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

import coop_loc_env
from policies.scripted.wander import WanderPolicy

LOCALIZED_M = 1.5  # Fox et al.: a robot is localized when its error is below 1.5 m
HOLD_S = 60.0  # s: the hexagon's "stays localized" window at the end of an episode
CONDITIONS = ("without_detections", "with_detections")

__all__ = [
    "CONDITIONS",
    "LOCALIZED_M",
    "bootstrap_over_seeds",
    "plot_error_vs_time",
    "robot_times_to_localize",
    "run_fox_episode",
    "run_hallway_experiment",
    "run_hexagon_experiment",
    "summarize_times",
]


def robot_times_to_localize(
    spread: np.ndarray, dt: float, threshold: float = LOCALIZED_M
) -> tuple[np.ndarray, np.ndarray]:
    """First time (s) each robot's spread falls below ``threshold``, and whether it did.

    ``spread`` is ``(T, n)``, row ``k`` the spread after step ``k + 1`` (time
    ``(k + 1) * dt``). Robots that never get below count at the time limit
    ``T * dt``.
    """
    spread = np.asarray(spread, dtype=float)
    if spread.ndim != 2 or spread.shape[0] < 1:
        raise ValueError(f"spread must be (T >= 1, n), got shape {spread.shape}")
    if not dt > 0:
        raise ValueError(f"dt must be > 0, got {dt!r}")
    below = spread < threshold
    reached = below.any(axis=0)
    first = np.where(reached, below.argmax(axis=0) + 1, spread.shape[0])
    return first * dt, reached


def run_fox_episode(
    scenario: str,
    seed: int,
    detections: bool,
    duration_s: float | None = None,
    speed: float = 0.6,
    **overrides: Any,
) -> dict[str, Any]:
    """One episode with the wander policy; ``detections`` switches belief transfer.

    Returns ``time_s (T,)``, ``spread_m (T, n)``, ``position_error_m (T, n)``,
    ``sensor`` (range-sensor type per robot), ``dt`` and ``detections_used``
    (transfers each robot received).
    """
    if duration_s is not None:
        dt = coop_loc_env.make_config(scenario, **overrides).dt
        overrides["max_cycles"] = max(1, int(round(duration_s / dt)))
    env = coop_loc_env.parallel_env(scenario, cooperative_updates=detections, **overrides)
    cfg = env.config
    if cfg.estimator != "mcl" and any(
        cfg.robot_spec(i).estimator != "mcl" for i in range(cfg.n_robots)
    ):
        raise ValueError(f"scenario {scenario!r} must run estimator='mcl', got {cfg.estimator!r}")
    obs, _ = env.reset(seed=seed)
    policy = WanderPolicy(speed)
    policy.reset(env, seed=seed)
    agents = list(env.possible_agents)
    spread, err = [], []
    infos: dict[str, dict] = {}
    while env.agents:
        obs, _, _, _, step_infos = env.step(policy.act(obs))
        infos.update(step_infos)  # robots that left keep their last figures
        spread.append([infos[a]["particle_spread"] for a in agents])
        err.append([infos[a]["position_error"] for a in agents])
    steps = len(spread)
    return {
        "time_s": (np.arange(steps) + 1) * cfg.dt,
        "spread_m": np.array(spread),
        "position_error_m": np.array(err),
        "sensor": [cfg.robot_spec(i).range_sensor for i in range(cfg.n_robots)],
        "dt": cfg.dt,
        "detections_used": [int(infos[a]["detections_used"]) for a in agents],
    }


def bootstrap_over_seeds(
    per_seed: dict[str, np.ndarray], stat, n_boot: int = 10000, seed: int = 0,
) -> tuple[float, float]:
    """95 % percentile bootstrap interval of ``stat(per_seed)`` resampling whole seeds.

    ``per_seed`` maps names to ``(S, ...)`` arrays with one row per seed (the same seeds
    in every array, so paired conditions stay paired); ``stat`` takes such a dict.
    """
    sizes = {len(v) for v in per_seed.values()}
    if len(sizes) != 1 or 0 in sizes:
        raise ValueError(f"per_seed arrays must have the same number (>= 1) of seeds, "
                         f"got {sorted(sizes)}")
    n = sizes.pop()
    rng = np.random.default_rng(seed)
    boots = np.empty(n_boot)
    for b in range(n_boot):
        idx = rng.integers(0, n, size=n)
        boots[b] = stat({k: np.asarray(v)[idx] for k, v in per_seed.items()})
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return float(lo), float(hi)


def _reduction(per_seed: dict[str, np.ndarray]) -> float:
    """% reduction of the mean time to localize with detections vs without."""
    return 100.0 * (1.0 - per_seed["with_detections"].mean()
                    / per_seed["without_detections"].mean())


def summarize_times(times: np.ndarray, reached: np.ndarray) -> dict[str, float | int]:
    """``mean_s``, ``std_s`` over robots (time limit for those that never localized),
    ``not_localized`` (how many never did) and ``robots``."""
    times = np.asarray(times, dtype=float).ravel()
    reached = np.asarray(reached, dtype=bool).ravel()
    return {
        "mean_s": float(times.mean()),
        "std_s": float(times.std(ddof=1)) if times.size > 1 else 0.0,
        "not_localized": int((~reached).sum()),
        "robots": int(times.size),
    }


def _progress(total: int, desc: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="episode")


def _run_conditions(
    scenario: str, seeds: Iterable[int], duration_s: float | None, progress: bool,
    **overrides: Any,
) -> dict[str, list[dict[str, Any]]]:
    seeds = list(seeds)
    if not seeds:
        raise ValueError("seeds must not be empty")
    bar = _progress(2 * len(seeds), scenario, progress)
    runs: dict[str, list[dict[str, Any]]] = {c: [] for c in CONDITIONS}
    for seed in seeds:
        for cond in CONDITIONS:
            ep = run_fox_episode(
                scenario, seed, cond == "with_detections", duration_s, **dict(overrides)
            )
            runs[cond].append(ep)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(seed=seed, condition=cond.split("_")[0])
    if bar is not None:
        bar.close()
    return runs


def _condition_figures(episodes: list[dict[str, Any]]) -> tuple[dict, np.ndarray, np.ndarray]:
    times, reached = zip(
        *(robot_times_to_localize(ep["spread_m"], ep["dt"]) for ep in episodes), strict=True
    )
    times, reached = np.concatenate(times), np.concatenate(reached)
    return summarize_times(times, reached), times, reached


def _curves(runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """Mean spread over robots and seeds vs time per condition (shortest run's length)."""
    out = {}
    for cond, eps in runs.items():
        steps = min(len(ep["time_s"]) for ep in eps)
        out[cond] = {
            "time_s": eps[0]["time_s"][:steps],
            "mean_spread_m": np.mean([ep["spread_m"][:steps].mean(axis=1) for ep in eps], axis=0),
        }
    return out


def run_hallway_experiment(
    seeds: Iterable[int] = range(8),
    duration_s: float | None = None,
    progress: bool = True,
    **overrides: Any,
) -> dict[str, Any]:
    """``symmetric_hallway`` with and without detections over ``seeds``.

    Returns per condition ``{"mean_s", "std_s", "not_localized", "robots"}``,
    ``reduction_pct`` (of the mean time with detections vs without) with
    ``reduction_ci95_pct`` (95 % bootstrap interval over seeds),
    ``per_seed_mean_s`` (per condition, one mean per seed) and ``curves``
    (mean spread vs time per condition, for the plot).
    """
    runs = _run_conditions("symmetric_hallway", seeds, duration_s, progress, **overrides)
    result = _time_figures(runs)
    result["curves"] = _curves(runs)
    return result


def _time_figures(runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """Each condition's time figures, the reduction with detections and its interval."""
    result: dict[str, Any] = {}
    for cond in CONDITIONS:
        result[cond], _, _ = _condition_figures(runs[cond])
    alone = result["without_detections"]["mean_s"]
    result["reduction_pct"] = 100.0 * (1.0 - result["with_detections"]["mean_s"] / alone)
    _seed_statistics(result, runs)
    return result


def _seed_statistics(result: dict[str, Any], runs: dict[str, list[dict[str, Any]]]) -> None:
    """Per-seed mean times per condition (``per_seed_mean_s``) and the reduction's bootstrap
    interval over seeds (``reduction_ci95_pct``; every seed has as many robots, so the
    mean of the seed means is the mean over robots)."""
    per_seed = {c: np.array([robot_times_to_localize(ep["spread_m"], ep["dt"])[0].mean()
                             for ep in runs[c]]) for c in CONDITIONS}
    result["per_seed_mean_s"] = {c: per_seed[c].tolist() for c in CONDITIONS}
    result["reduction_ci95_pct"] = list(bootstrap_over_seeds(per_seed, _reduction))


def run_hexagon_experiment(
    seeds: Iterable[int] = range(4),
    duration_s: float | None = None,
    progress: bool = True,
    **overrides: Any,
) -> dict[str, Any]:
    """``hexagon`` (4 sonar + 4 laser robots) with and without detections over ``seeds``.

    Returns the hallway's figures over all robots, plus ``by_sensor``: per
    sensor type and condition, ``localized_at_end`` (robots whose final spread
    is below 1.5 m), ``localized_last_60s`` (below 1.5 m at every step of the
    last ``HOLD_S`` seconds), ``localized_at_end_ci95`` (of the fraction
    localized at the end, 95 % bootstrap interval over seeds), ``ever_localized``, ``robots``,
    ``mean_final_spread_m`` and the time figures; and ``curves`` per condition
    and sensor type. In the hexagon a robot alone keeps two or three copies of
    its pose, whose mean distance from the truth drops below 1.5 m whenever it
    passes within 1.3 to 1.5 m of the centre (the copies are then close
    together), so ``ever_localized`` and the time figures overstate what a
    lone robot knows; the final and held figures do not.
    """
    runs = _run_conditions("hexagon", seeds, duration_s, progress, **overrides)
    result = _time_figures(runs)
    by_sensor: dict[str, dict[str, Any]] = {}
    curves: dict[str, Any] = {}
    for sensor in ("sonar", "laser"):
        by_sensor[sensor] = {}
        for cond in CONDITIONS:
            eps = runs[cond]
            cols = [np.array([s == sensor for s in ep["sensor"]]) for ep in eps]
            final = np.concatenate([ep["spread_m"][-1, c] for ep, c in zip(eps, cols, strict=True)])
            tr = [robot_times_to_localize(ep["spread_m"][:, c], ep["dt"])
                  for ep, c in zip(eps, cols, strict=True)]
            times = np.concatenate([t for t, _ in tr])
            reached = np.concatenate([r for _, r in tr])
            held = np.concatenate([
                (ep["spread_m"][-max(1, int(round(HOLD_S / ep["dt"]))):, c] < LOCALIZED_M
                 ).all(axis=0)
                for ep, c in zip(eps, cols, strict=True)
            ])
            at_end = np.array([(ep["spread_m"][-1, c] < LOCALIZED_M).mean()
                               for ep, c in zip(eps, cols, strict=True)])
            by_sensor[sensor][cond] = {
                **summarize_times(times, reached),
                "localized_at_end": int((final < LOCALIZED_M).sum()),
                "localized_at_end_ci95": list(bootstrap_over_seeds(
                    {"f": at_end}, lambda d: float(d["f"].mean()))),
                "localized_last_60s": int(held.sum()),
                "ever_localized": int(reached.sum()),
                "mean_final_spread_m": float(final.mean()),
            }
            steps = min(len(ep["time_s"]) for ep in eps)
            curves[f"{cond}_{sensor}"] = {
                "time_s": eps[0]["time_s"][:steps],
                "mean_spread_m": np.mean(
                    [ep["spread_m"][:steps, c].mean(axis=1) for ep, c in zip(eps, cols,
                                                                             strict=True)],
                    axis=0,
                ),
            }
    result["by_sensor"] = by_sensor
    result["curves"] = curves
    return result


def plot_error_vs_time(curves: dict[str, Any], path: str | Path, title: str = "") -> Path:
    """Mean particle spread vs time, one line per entry of ``curves``; 1.5 m dotted."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7, 4), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    for k, (name, c) in enumerate(curves.items()):
        style = "-" if "with_detections" in name else "--"
        ax.plot(c["time_s"], c["mean_spread_m"], style, color=f"C{k // 2}" if len(curves) > 2
                else "k", lw=1.5, label=name.replace("_", " "))
    ax.axhline(LOCALIZED_M, color="grey", ls=":", lw=1, label="localized (1.5 m)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("mean particle spread (m)")
    ax.set_title(title or "localization error vs time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path
