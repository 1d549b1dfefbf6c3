"""Compare policies on one scenario: means with 95 % confidence intervals, a table and a bar plot.

Used by ``scripts/evaluate.py --compare fsm,random,PATH.zip``. Every policy
runs the same seeded episodes (episode ``k`` seeded ``seed + k``); policies
are the specs of :func:`policies.learning.loader.make_policy` (a registered name, e.g.
``wander:0.8``, or a saved model).
Figures per episode are those of :mod:`policies.episode` plus
``time_to_localize_s``: per robot, the first time its spread falls below
1.5 m (MCL: ``info["particle_spread"]``, the weighted mean particle distance
from the truth; otherwise ``sqrt(var_x + var_y)`` of the belief), averaged
over the robots; a robot that never gets there counts the episode length (a
censored, optimistic value, flagged by ``localized_fraction``, the fraction
of robots that got there), and ``localized_at_end``, the fraction of robots
whose spread is below 1.5 m at the last step (a robot that localized and then
lost its belief counts in the first two, not in this one).

The 95 % interval of a mean over ``n`` episodes is ``mean +/- t(0.975, n-1) *
s / sqrt(n)`` (Student t, ``s`` the sample standard deviation).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from policies.episode import FIGURES, env_overrides_for, episode_figures, run_episode
from policies.experiments.fox import LOCALIZED_M, robot_times_to_localize
from policies.learning.loader import make_policy
from policies.scripted.baselines import StandStillPolicy  # noqa: F401 (re-exported)

COMPARE_FIGURES = FIGURES + ("time_to_localize_s", "localized_fraction", "localized_at_end")
LABELS = {
    "localization_error_m": "team loc. error (m)",
    "coverage": "coverage",
    "map_rmse_m": "map RMSE (m)",
    "collisions": "collisions",
    "tip_overs": "tip-overs",
    "time_to_localize_s": "time to localize (s)",
    "localized_fraction": "localized",
    "localized_at_end": "localized at end",
}
SPREAD_THRESHOLD = LOCALIZED_M
# The range each figure can take: its confidence interval is clipped to it (a
# Student-t interval of counts or fractions near a bound would leave it).
FIGURE_BOUNDS = {
    "coverage": (0.0, 1.0),
    "localized_fraction": (0.0, 1.0),
    "localized_at_end": (0.0, 1.0),
}


def parse_policy_list(text: str) -> list[str]:
    """``"fsm,random,PATH"`` -> ``["fsm", "random", "PATH"]``; rejects empty or repeated entries."""
    specs = [s.strip() for s in str(text).split(",")]
    if not specs or any(not s for s in specs):
        raise ValueError(f"--compare expects a comma-separated list of policies, got {text!r}")
    if len(set(specs)) != len(specs):
        raise ValueError(f"--compare lists a policy twice: {text!r}")
    return specs


def resolve_policy(spec: str):
    """:func:`policies.learning.loader.make_policy` (kept under this name for existing callers)."""
    return make_policy(spec)


def episode_time_to_localize(ep: dict[str, Any], dt: float, threshold: float = SPREAD_THRESHOLD
                     ) -> tuple[float, float]:
    """``(mean time to localize (s), fraction of robots localized)`` of one episode record.

    The spread is ``ep["series"]["particle_spread_m"]`` when the episode has it
    (MCL: weighted mean particle distance from the truth, Fox et al.'s measure),
    else ``sqrt(var_x + var_y)`` of the belief covariance.
    """
    times, done = robot_times_to_localize(_spread(ep), dt, threshold)
    return float(times.mean()), float(done.mean())


def localized_at_end(ep: dict[str, Any], threshold: float = SPREAD_THRESHOLD) -> float:
    """Fraction of the robots whose spread (as in :func:`episode_time_to_localize`) is below
    ``threshold`` at the episode's last step."""
    return float((_spread(ep)[-1] < threshold).mean())


def _spread(ep: dict[str, Any]) -> np.ndarray:
    """``(T, n)`` spread per step and robot: the particle spread when the episode has it."""
    if "particle_spread_m" in ep["series"]:
        return np.asarray(ep["series"]["particle_spread_m"], dtype=float)
    # position_std_m is sqrt(0.5 (var_x + var_y))
    return np.sqrt(2.0) * np.asarray(ep["series"]["position_std_m"], dtype=float)


def mean_ci(
    values: np.ndarray, level: float = 0.95, bounds: tuple[float, float] | None = None
) -> tuple[float, float, float]:
    """``(mean, low, high)`` of the Student-t ``level`` interval of the mean.

    ``bounds`` (low, high), when given, clip the interval to the values the mean
    can take (a mean of counts is never negative, a fraction never above 1).
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return float("nan"), float("nan"), float("nan")
    m = float(v.mean())
    if len(v) < 2:
        return m, float("nan"), float("nan")
    half = float(stats.t.ppf(0.5 + level / 2, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v)))
    low, high = m - half, m + half
    if bounds is not None:
        low, high = max(low, bounds[0]), min(high, bounds[1])
    return m, low, high


def compare(
    scenario: str,
    specs: list[str],
    n_episodes: int = 20,
    seed: int = 0,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
    on_policy_done=None,
) -> dict[str, Any]:
    """Run every policy of ``specs`` on the same seeds; returns the comparison report.

    The report holds ``scenario``, ``n_episodes``, ``seed``, ``policies`` (the
    specs), ``summary[spec][figure] = {"mean", "low", "high"}`` and
    ``episodes[spec]`` (per-episode figures). ``on_policy_done(report)``, when
    given, is called after each policy with the report of the policies done so
    far (``scripts/evaluate.py`` saves it, so a long comparison cut short keeps them).
    """
    import coop_loc_env

    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be a positive integer, got {n_episodes!r}")
    dt = coop_loc_env.make_config(scenario, **(overrides or {})).dt
    policies = [resolve_policy(s) for s in specs]  # fail before running anything
    summary: dict[str, dict[str, dict[str, float]]] = {}
    episodes: dict[str, list[dict[str, Any]]] = {}
    for spec, policy in zip(specs, policies, strict=True):
        eps = _run(scenario, policy, n_episodes, seed, overrides or {}, progress, spec)
        records = []
        for ep in eps:
            t_loc, frac = episode_time_to_localize(ep, dt)
            robot_t, robot_done = robot_times_to_localize(_spread(ep), dt, SPREAD_THRESHOLD)
            rec = episode_figures(ep)
            rec["robot_times_to_localize_s"] = robot_t.tolist()
            rec["robot_localized"] = robot_done.tolist()
            rec["time_to_localize_s"] = t_loc
            rec["localized_fraction"] = frac
            rec["localized_at_end"] = localized_at_end(ep)
            records.append(rec)
        episodes[spec] = records
        summary[spec] = {}
        for key in COMPARE_FIGURES:
            m, lo, hi = mean_ci(np.array([r[key] for r in records], dtype=float),
                                bounds=FIGURE_BOUNDS.get(key, (0.0, np.inf)))
            summary[spec][key] = {"mean": m, "low": lo, "high": hi}
        if on_policy_done is not None:
            on_policy_done(_report(scenario, n_episodes, seed, list(summary), overrides,
                                   summary, episodes))
    return _report(scenario, n_episodes, seed, specs, overrides, summary, episodes)


def _report(scenario, n_episodes, seed, specs, overrides, summary, episodes) -> dict[str, Any]:
    return {"scenario": scenario, "n_episodes": n_episodes, "seed": seed,
            "policies": list(specs), "overrides": dict(overrides or {}), "summary": summary,
            "episodes": episodes}


def _run(scenario: str, policy, n_episodes: int, seed: int, overrides: dict[str, Any],
         progress: bool, label: str) -> list[dict[str, Any]]:
    """:func:`policies.episode.run_episode` for each seed, also recording ``particle_spread``
    (when the estimator reports it) as ``series["particle_spread_m"]``."""
    import coop_loc_env

    env = coop_loc_env.parallel_env(scenario, **env_overrides_for(policy, overrides))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_episodes * env.config.max_cycles, unit="step",
                   desc=f"{scenario} {policy_label(label)}")
    n = env.config.n_robots
    out = []
    try:
        for k in range(n_episodes):
            rows: list[np.ndarray] = []
            last = np.full(n, np.nan)

            def on_step(e, infos, rows=rows, last=last):
                for agent, info in infos.items():
                    if "particle_spread" in info:
                        last[e.agent_name_mapping[agent]] = info["particle_spread"]
                rows.append(last.copy())  # robots that left keep their last spread
                if bar is not None:
                    bar.update()

            ep = run_episode(env, policy, seed + k, on_step)
            if rows and np.isfinite(rows[-1]).any():
                ep["series"]["particle_spread_m"] = np.array(rows)
            if bar is not None:
                bar.update(env.config.max_cycles - ep["steps"])
            out.append(ep)
    finally:
        if bar is not None:
            bar.close()
        env.close()
    return out


def localized_from_the_start(report: dict[str, Any], dt: float) -> bool:
    """Whether every robot of every episode of every policy was localized (spread below
    the threshold) at the first step: time to localize then says nothing about the policies."""
    return all(
        rec["localized_fraction"] == 1.0 and rec["time_to_localize_s"] <= dt * (1 + 1e-9)
        for recs in report["episodes"].values() for rec in recs
    )


def paired_difference(report: dict[str, Any], a: str, b: str,
                      figure: str = "time_to_localize_s", level: float = 0.95
                      ) -> dict[str, float]:
    """Mean and Student-t interval of ``figure(a) - figure(b)`` over the episodes both
    policies ran on the same seeds (a paired comparison: the seed's start poses are
    shared, so their variance cancels); also ``n``."""
    ea, eb = report["episodes"][a], report["episodes"][b]
    if len(ea) != len(eb):
        raise ValueError(f"{a!r} and {b!r} ran different numbers of episodes: "
                         f"{len(ea)} vs {len(eb)}")
    d = np.array([x[figure] for x in ea], dtype=float) - np.array([y[figure] for y in eb],
                                                                  dtype=float)
    m, lo, hi = mean_ci(d, level)
    return {"mean": m, "low": lo, "high": hi, "n": len(d)}


def format_paired(report: dict[str, Any], reference: str,
                  figure: str = "time_to_localize_s") -> str:
    """Lines ``policy - reference: mean [low, high]`` of :func:`paired_difference` for every
    other policy of ``report``."""
    lines = [f"paired difference in {LABELS[figure]} vs {policy_label(reference)} "
             f"(same seeds, 95 % CI):"]
    for spec in report["policies"]:
        if spec == reference:
            continue
        d = paired_difference(report, spec, reference, figure)
        lines.append(f"  {policy_label(spec)}: {d['mean']:+.4g} [{d['low']:+.4g}, "
                     f"{d['high']:+.4g}]")
    return "\n".join(lines)


def merge_reports(reports: list[dict[str, Any]]) -> dict[str, Any]:
    """One report from several :func:`compare` reports of disjoint policies on the same
    scenario, episodes and seed (e.g. policies run in parallel processes)."""
    if not reports:
        raise ValueError("merge_reports needs at least one report, got []")
    first = reports[0]
    out = {**first, "policies": [], "summary": {}, "episodes": {}}
    for rep in reports:
        for key in ("scenario", "n_episodes", "seed", "overrides"):
            if rep.get(key) != first.get(key):
                raise ValueError(f"cannot merge reports with different {key}: "
                                 f"{first.get(key)!r} vs {rep.get(key)!r}")
        for spec in rep["policies"]:
            if spec in out["summary"]:
                raise ValueError(f"policy {spec!r} is in more than one report")
            out["policies"].append(spec)
            out["summary"][spec] = rep["summary"][spec]
            out["episodes"][spec] = rep["episodes"][spec]
    return out


def policy_label(spec: str) -> str:
    """A short label: the name, or ``parent/stem`` of a model path."""
    p = Path(spec)
    return f"{p.parent.name}/{p.stem}" if p.suffix == ".zip" else spec


def format_compare_table(report: dict[str, Any],
                         figures: tuple[str, ...] = COMPARE_FIGURES) -> str:
    """One table: a row per policy, ``mean [low, high]`` per figure (95 % CI)."""
    specs = report["policies"]
    names = [policy_label(s) for s in specs]
    width = max(10, *(len(n) for n in names))
    cols = []
    for key in figures:
        cells = []
        for spec in specs:
            s = report["summary"][spec][key]
            cells.append(f"{s['mean']:.4g} [{s['low']:.4g}, {s['high']:.4g}]")
        cols.append((LABELS[key], cells))
    widths = [max(len(label), *(len(c) for c in cells)) for label, cells in cols]
    head = f"{'policy':<{width}}  " + "  ".join(
        f"{label:<{w}}" for (label, _), w in zip(cols, widths, strict=True))
    lines = [f"{report['scenario']}: mean [95 % CI] over {report['n_episodes']} episodes "
             f"(seeds {report['seed']}..{report['seed'] + report['n_episodes'] - 1})", head,
             "-" * len(head)]
    for r, name in enumerate(names):
        lines.append(f"{name:<{width}}  " + "  ".join(
            f"{cells[r]:<{w}}" for (_, cells), w in zip(cols, widths, strict=True)))
    return "\n".join(lines)


def plot_compare(report: dict[str, Any], path: str | Path,
                 figures: tuple[str, ...] = ("localization_error_m", "coverage",
                                             "time_to_localize_s", "collisions")) -> Path:
    """Bar plot (one panel per figure, one bar per policy, 95 % CI error bars) saved to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    specs = report["policies"]
    names = [policy_label(s) for s in specs]
    fig, axes = plt.subplots(1, len(figures), figsize=(3.6 * len(figures), 3.6))
    axes = np.atleast_1d(axes)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, key in zip(axes, figures, strict=True):
        s = [report["summary"][spec][key] for spec in specs]
        means = np.array([v["mean"] for v in s])
        err = np.array([[v["mean"] - v["low"], v["high"] - v["mean"]] for v in s]).T
        err = np.nan_to_num(err)
        ax.bar(range(len(specs)), means, yerr=err, capsize=4,
               color=[colors[i % len(colors)] for i in range(len(specs))])
        ax.set_xticks(range(len(specs)), names, rotation=20, ha="right", fontsize=8)
        ax.set_title(LABELS[key], fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"{report['scenario']}: mean and 95 % CI over {report['n_episodes']} episodes",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
