"""Do the MCL belief's mode weights mean what they say? A reliability table, with honesty figures.

An evaluation tool: it reads the true poses, which no policy may. Runs a scenario
(``active_hallway`` by default; any scenario whose robots run MCL) with a policy
(``corridor`` by default) and, at every step and for every robot, takes the top mode
of its belief exactly as the dict observation's ``belief_modes`` block extracts it
(:class:`coop_loc_env.belief_map.BeliefModesBlock`). A mode is *right* when it lies
within 1 m and 0.3 rad of the true pose. Figures:

* ``bins``: for top-mode weight bins (below 0.5, 0.5-0.6, ..., 0.9-0.99, >= 0.99) the
  robot steps, the mean weight, the fraction right with a 95 % Wilson interval (steps
  of one episode are correlated: read it as a lower bound on the uncertainty) and
  the gap ``right - mean weight``; a calibrated belief has every gap near 0;
* ``confident_wrong_pct``, ``lost`` (robots whose ``particle_spread`` fell below
  1.5 m and is 1.5 m or more at the end), ``time_to_localize_s``: as
  ``scripts/bench/detection_honesty.py`` defines them;
* ``meetings``: robots not localized (spread 1.5 m or more) that a localized
  teammate detects (a genuine detection, states read before the step that uses it):
  how many, how many then held a wrong top mode weighing 0.9 or more
  (``wrong_confident``), and the time from that first meeting to localized
  (``meet_to_localized_s``: 0 when the step that uses the detection localizes it; a
  robot that never gets there counts until the episode ends, ``never`` counts them),
  per group.

::

    python scripts/bench/mode_reliability.py --episodes 10 --seed 1000
    python scripts/bench/mode_reliability.py --scenario symmetric_hallway --json out.json
    python scripts/bench/mode_reliability.py --set "extras={mcl_calibrated_copies: true}"

``--set extras=...`` is set over the scenario's own extras (its MCL tuning), not in
place of them, so one backend option can be switched alone (above: the kept symmetric
copies share the top mode's weight, ``extras["mcl_calibrated_copies"]``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

import coop_loc_env
from coop_loc_env.belief_map import BeliefModesBlock, TeamBeliefs
from estimators.geometry import wrap_angle
from policies.episode import env_overrides_for
from policies.experiments.runner import parse_overrides
from policies.learning.loader import make_policy

RIGHT_M = 1.0  # m: a top mode this close to the true position ...
RIGHT_RAD = 0.3  # ... and this close to the true heading is right
CONFIDENT_STD_M = 1.0  # confident and wrong: pose_cov position std below this ...
WRONG_M = 3.0  # ... and position error above this
LOCALIZED_M = 1.5  # particle spread below which a robot is localized
MEET_CONFIDENT = 0.9  # a met robot whose wrong top mode weighs this much was confidently wrong
BIN_EDGES = (0.5, 0.6, 0.7, 0.8, 0.9, 0.99)
BIN_LABELS = ("<0.5", "0.5-0.6", "0.6-0.7", "0.7-0.8", "0.8-0.9", "0.9-0.99", ">=0.99")


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a binomial fraction ``k / n`` (``(0, 1)`` for ``n = 0``)."""
    if n <= 0:
        return 0.0, 1.0
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, mid - half), min(1.0, mid + half)


def weight_bin(w: np.ndarray) -> np.ndarray:
    """Index into :data:`BIN_LABELS` of each top-mode weight."""
    return np.searchsorted(np.asarray(BIN_EDGES), np.asarray(w, dtype=float), side="right")


def top_mode_right(modes: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``(n,)``: whether each robot's top mode (row 0 of ``(n, K, 6)`` raw modes) lies within
    ``RIGHT_M`` and ``RIGHT_RAD`` of its true pose ``(n, 3)``."""
    top = modes[:, 0]
    dist = np.hypot(top[:, 1] - truth[:, 0], top[:, 2] - truth[:, 1])
    dh = np.abs(wrap_angle(np.arctan2(top[:, 4], top[:, 3]) - truth[:, 2]))
    return (top[:, 0] > 0) & (dist <= RIGHT_M) & (dh <= RIGHT_RAD)


def run_episode(seed: int, policy_spec: str, scenario: str, overrides: dict) -> dict:
    """One episode's per-step series, reduced to the figures of the module docstring."""
    policy = make_policy(policy_spec)
    env = coop_loc_env.parallel_env(scenario, **env_overrides_for(policy, overrides))
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed=seed)
    block = BeliefModesBlock(env.config)
    agents = list(env.possible_agents)
    rows = [env.agent_name_mapping[a] for a in agents]
    dt = env.config.dt
    weight, right, std, err, spread = [], [], [], [], []
    meets: list[tuple[int, int, int]] = []  # (step, observer, target) of genuine detections
    infos: dict = {}
    while env.agents:
        obs, _, _, _, step_infos = env.step(policy.act(obs))
        infos.update(step_infos)
        det = env.last_readings.detections if env.last_readings is not None else None
        if det is not None and len(det):
            for o, t, g in zip(det.observer.tolist(), det.target.tolist(),
                               det.genuine.tolist(), strict=True):
                if g:
                    meets.append((len(weight), o, t))
        modes = block.modes(TeamBeliefs.from_env(env))
        truth = np.asarray(env.world.poses, dtype=float)
        weight.append(modes[rows, 0, 0])
        right.append(top_mode_right(modes[rows], truth[rows]))
        cov = np.array([infos[a]["pose_cov"] for a in agents], dtype=float)
        std.append(np.sqrt(cov[:, 0, 0] + cov[:, 1, 1]))
        err.append([float(infos[a]["position_error"]) for a in agents])
        spread.append([float(infos[a]["particle_spread"]) for a in agents])
    weight, right = np.array(weight), np.array(right)
    std, err, spread = np.array(std), np.array(err), np.array(spread)
    env.close()
    return reduce_episode(seed, weight, right, std, err, spread, meets, rows, dt)


def reduce_episode(seed: int, weight: np.ndarray, right: np.ndarray, std: np.ndarray,
                   err: np.ndarray, spread: np.ndarray, meets: list[tuple[int, int, int]],
                   rows: list[int], dt: float) -> dict:
    """Figures of one episode from its ``(steps, robots)`` series (see the module docstring).

    ``meets``: ``(step, observer, target)`` global robot indices of the genuine detections
    used at series row ``step`` (the robots' states before it are row ``step - 1``).
    """
    steps = len(weight)
    idx = weight_bin(weight)
    bins = [[int((idx == b).sum()), int(right[idx == b].sum()), float(weight[idx == b].sum())]
            for b in range(len(BIN_LABELS))]
    below = spread < LOCALIZED_M
    reached = below.any(axis=0)
    first = np.where(reached, below.argmax(axis=0), steps)  # row of first localized
    col = {g: c for c, g in enumerate(rows)}
    met: dict[int, tuple[int, bool]] = {}  # robot column -> (row of meeting, wrong confident)
    for step, o, t in meets:
        if step == 0 or o not in col or t not in col or col[t] in met:
            continue
        co, ct = col[o], col[t]
        if below[step - 1, co] and not below[step - 1, ct]:
            wrong = (not right[step - 1, ct]) and weight[step - 1, ct] >= MEET_CONFIDENT
            met[ct] = (step, bool(wrong))
    meetings = []
    for c, (step, wrong) in sorted(met.items()):
        after = below[step:, c]
        done = bool(after.any())
        wait = (int(after.argmax()) if done else steps - 1 - step) * dt  # rows of time
        meetings.append({"wrong_confident": wrong, "meet_to_localized_s": wait,
                         "localized": done})
    cw = (std < CONFIDENT_STD_M) & (err > WRONG_M)
    return {
        "seed": int(seed),
        "samples": int(cw.size),
        "bins": bins,
        "confident_wrong": int(cw.sum()),
        "localized": int(reached.sum()),
        "lost": int((reached & ~below[-1]).sum()),
        "robots": len(rows),
        "time_to_localize_s": (np.where(reached, first + 1, steps) * dt).tolist(),
        "meetings": meetings,
    }


def _meeting_summary(items: list[dict]) -> dict:
    waits = np.array([m["meet_to_localized_s"] for m in items], dtype=float)
    return {
        "robots": len(items),
        "meet_to_localized_s": float(waits.mean()) if len(waits) else None,
        "median_s": float(np.median(waits)) if len(waits) else None,
        "never": sum(not m["localized"] for m in items),
    }


def summarize(episodes: list[dict]) -> dict:
    """Totals over episodes: the reliability bins, honesty figures and meetings."""
    if not episodes:
        raise ValueError("summarize needs at least one episode")
    counts = np.sum([e["bins"] for e in episodes], axis=0)
    bins = []
    for label, (n, k, wsum) in zip(BIN_LABELS, counts.tolist(), strict=True):
        n, k = int(n), int(k)
        mean_w = wsum / n if n else None
        frac = k / n if n else None
        lo, hi = wilson(k, n)
        bins.append({"bin": label, "steps": n, "mean_weight": mean_w, "right": frac,
                     "right_ci95": [lo, hi],
                     "gap": None if n == 0 else frac - mean_w})
    samples = sum(e["samples"] for e in episodes)
    loc = sum(e["localized"] for e in episodes)
    lost = sum(e["lost"] for e in episodes)
    per_seed = [float(np.mean(e["time_to_localize_s"])) for e in episodes]
    meets = [m for e in episodes for m in e["meetings"]]
    wrong = [m for m in meets if m["wrong_confident"]]
    calibrated = [b["gap"] for b in bins[1:] if b["gap"] is not None]
    return {
        "episodes": len(episodes),
        "bins": bins,
        "max_abs_gap": max((abs(g) for g in calibrated), default=None),
        "confident_wrong_pct": 100.0 * sum(e["confident_wrong"] for e in episodes) / samples,
        "localized": loc,
        "robots": sum(e["robots"] for e in episodes),
        "lost": lost,
        "time_to_localize_s": float(np.mean(per_seed)),
        "meetings": {
            "all": _meeting_summary(meets),
            "wrong_confident": _meeting_summary(wrong),
            "other": _meeting_summary([m for m in meets if not m["wrong_confident"]]),
            "wrong_confident_pct": 100.0 * len(wrong) / len(meets) if meets else None,
        },
    }


def format_table(summary: dict) -> str:
    """The reliability bins and the honesty figures as plain text."""
    lines = ["top-mode weight | steps | mean weight | right | 95 % interval | gap"]
    for b in summary["bins"]:
        if b["steps"] == 0:
            lines.append(f"{b['bin']:>15} | 0 | - | - | - | -")
            continue
        lo, hi = b["right_ci95"]
        lines.append(f"{b['bin']:>15} | {b['steps']} | {b['mean_weight']:.3f} | "
                     f"{b['right']:.3f} | {lo:.3f}-{hi:.3f} | {b['gap']:+.3f}")
    m = summary["meetings"]
    lines.append(
        f"confident and wrong {summary['confident_wrong_pct']:.2f} %, "
        f"lost {summary['lost']} of {summary['localized']} localized "
        f"({summary['robots']} robots), time to localize {summary['time_to_localize_s']:.2f} s")
    for key in ("all", "wrong_confident", "other"):
        g = m[key]
        wait = "-" if g["meet_to_localized_s"] is None else (
            f"{g['meet_to_localized_s']:.2f} s (median {g['median_s']:.2f} s)")
        lines.append(f"met lost robots, {key}: {g['robots']}, meeting to localized {wait}, "
                     f"never {g['never']}")
    return "\n".join(lines)


def with_scenario_extras(scenario: str, overrides: dict) -> dict:
    """``overrides`` with its ``extras`` (if any) set over ``scenario``'s own extras."""
    if "extras" not in overrides:
        return overrides
    extras = overrides["extras"]
    if not isinstance(extras, dict):
        raise ValueError(f"--set extras must be a mapping, got {extras!r}")
    base = coop_loc_env.make_config(scenario).extras
    return {**overrides, "extras": {**base, **extras}}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="active_hallway")
    parser.add_argument("--policy", default="corridor")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1000,
                        help="first seed; episode k is seeded seed + k (default 1000)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE",
                        help="config override, repeatable (extras=... is set over the "
                             "scenario's own extras)")
    parser.add_argument("--json", default=None, help="also write the figures (and episodes) here")
    parser.add_argument("--quiet", action="store_true", help="no line per episode")
    args = parser.parse_args(argv)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        overrides = with_scenario_extras(args.scenario, parse_overrides(args.overrides))
        make_policy(args.policy)
        coop_loc_env.parallel_env(args.scenario, **overrides).close()
    except (ValueError, KeyError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    episodes = []
    t0 = time.process_time()
    for k in range(args.episodes):
        ep = run_episode(args.seed + k, args.policy, args.scenario, overrides)
        episodes.append(ep)
        if not args.quiet:
            print(f"seed {ep['seed']}: lost {ep['lost']} "
                  f"ttl {np.mean(ep['time_to_localize_s']):.1f} s "
                  f"meetings {len(ep['meetings'])}", flush=True)
    out = summarize(episodes)
    out["cpu_s"] = time.process_time() - t0
    print(format_table(out), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"summary": out, "episodes": episodes, "scenario": args.scenario,
                       "policy": args.policy, "seed": args.seed,
                       "overrides": args.overrides}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
