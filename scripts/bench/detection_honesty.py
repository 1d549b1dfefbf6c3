"""Do MCL beliefs stay honest when teammates detect each other? Prints figures.

Runs ``active_hallway`` (four sonar robots localizing globally in the symmetric
ring) with a policy (``corridor`` by default) over seeds, and counts every robot
and step:

* ``confident_wrong``: share of belief samples whose position standard
  deviation from ``pose_cov`` (``sqrt(var_x + var_y)``) is under 1 m while
  the position error is over 3 m, and the largest such error;
* ``localized``: robots whose ``particle_spread`` fell below 1.5 m at some step,
  and ``lost``: those of them whose spread is 1.5 m or more at the end;
* ``time_to_localize_s``: mean over robots of the first time the spread is
  below 1.5 m (the episode length for a robot that never gets there), with a
  bootstrap 95 % interval over seeds; per-seed means go to the JSON so two
  runs on the same seeds can be paired;
* ``detection_conflicts``: detection conflicts the robots' infos report, summed
  over robots at the end of each episode (absent on code without the count).

    python scripts/bench/detection_honesty.py --seeds 30000:30040
    python scripts/bench/detection_honesty.py --seeds 30000:30040 --set cooperative_updates=False
    python scripts/bench/detection_honesty.py --policy still --json outputs/honesty.json
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

import coop_loc_env
from coop_loc_env.cli import ScriptParser, run_script
from policies.episode import env_overrides_for
from policies.experiments.runner import parse_overrides
from policies.learning.loader import make_policy

CONFIDENT_STD_M = 1.0
WRONG_M = 3.0
LOCALIZED_M = 1.5


def bootstrap_ci(values: np.ndarray, n_boot: int = 10000, seed: int = 0,
                 stat=np.mean) -> tuple[float, float]:
    """95 % percentile bootstrap interval of ``stat`` over ``values`` (resampled as a whole)."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise ValueError("bootstrap_ci needs at least one value")
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(v), size=(n_boot, len(v)))
    boots = stat(v[idx], axis=1)
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return float(lo), float(hi)


def run_episode(seed: int, policy_spec: str, scenario: str, overrides: dict) -> dict:
    """One episode: per robot and step, the honesty figures (see the module docstring)."""
    policy = make_policy(policy_spec)
    env = coop_loc_env.parallel_env(scenario, **env_overrides_for(policy, overrides))
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed=seed)
    agents = list(env.possible_agents)
    dt = env.config.dt
    std, err, spread = [], [], []
    infos: dict = {}
    while env.agents:
        obs, _, _, _, step_infos = env.step(policy.act(obs))
        infos.update(step_infos)
        row_s, row_e, row_p = [], [], []
        for a in agents:
            cov = np.asarray(infos[a]["pose_cov"], dtype=float)
            row_s.append(float(np.sqrt(cov[0, 0] + cov[1, 1])))
            row_e.append(float(infos[a]["position_error"]))
            row_p.append(float(infos[a]["particle_spread"]))
        std.append(row_s)
        err.append(row_e)
        spread.append(row_p)
    std, err, spread = np.array(std), np.array(err), np.array(spread)
    cw = (std < CONFIDENT_STD_M) & (err > WRONG_M)
    below = spread < LOCALIZED_M
    reached = below.any(axis=0)
    first = np.where(reached, below.argmax(axis=0) + 1, len(spread)) * dt
    conflicts = [infos[a].get("detection_conflicts") for a in agents]
    return {
        "seed": int(seed),
        "samples": int(cw.size),
        "confident_wrong": int(cw.sum()),
        "max_confident_wrong_error_m": float(err[cw].max()) if cw.any() else 0.0,
        "localized": int(reached.sum()),
        "lost": int((reached & ~below[-1]).sum()),
        "robots": len(agents),
        "time_to_localize_s": first.tolist(),
        "detection_conflicts": None if None in conflicts else int(sum(conflicts)),
    }


def summarize(episodes: list[dict]) -> dict:
    """Totals over episodes, with a bootstrap interval over seeds for the time to localize."""
    samples = sum(e["samples"] for e in episodes)
    cw = sum(e["confident_wrong"] for e in episodes)
    loc = sum(e["localized"] for e in episodes)
    lost = sum(e["lost"] for e in episodes)
    per_seed = np.array([np.mean(e["time_to_localize_s"]) for e in episodes])
    cw_seed = np.array([e["confident_wrong"] / e["samples"] for e in episodes])
    conflicts = [e["detection_conflicts"] for e in episodes]
    return {
        "episodes": len(episodes),
        "confident_wrong_pct": 100.0 * cw / samples,
        "confident_wrong_pct_ci95": [100 * x for x in bootstrap_ci(cw_seed)],
        "max_confident_wrong_error_m": max(e["max_confident_wrong_error_m"] for e in episodes),
        "localized": loc,
        "robots": sum(e["robots"] for e in episodes),
        "lost": lost,
        "lost_pct": 100.0 * lost / loc if loc else 0.0,
        "time_to_localize_s": float(per_seed.mean()),
        "time_to_localize_s_ci95": list(bootstrap_ci(per_seed)),
        "detection_conflicts": None if None in conflicts else int(sum(conflicts)),
    }


def parse_seeds(text: str) -> list[int]:
    """``A:B`` (A to B-1) or a comma-separated list."""
    try:
        if ":" in text:
            a, b = text.split(":")
            seeds = list(range(int(a), int(b)))
        else:
            seeds = [int(s) for s in text.split(",")]
    except ValueError as err:
        raise ValueError(f"--seeds must be A:B or a comma-separated list, got {text!r}") from err
    if not seeds:
        raise ValueError(f"--seeds selects no seed: {text!r}")
    return seeds


def main(argv: list[str] | None = None) -> int:
    parser = ScriptParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="30000:30040",
                        help="A:B or a list (default 30000:30040)")
    parser.add_argument("--policy", default="corridor")
    parser.add_argument("--scenario", default="active_hallway")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="config override, repeatable")
    parser.add_argument("--json", default=None, help="also write the figures (and episodes) here")
    parser.add_argument("--quiet", action="store_true", help="no line per episode")
    args = parser.parse_args(argv)
    try:
        seeds = parse_seeds(args.seeds)
        overrides = parse_overrides(args.overrides)
        make_policy(args.policy)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    episodes = []
    t0 = time.process_time()
    for seed in seeds:
        ep = run_episode(seed, args.policy, args.scenario, overrides)
        episodes.append(ep)
        if not args.quiet:
            print(f"seed {seed}: confident_wrong {ep['confident_wrong']}/{ep['samples']} "
                  f"localized {ep['localized']} lost {ep['lost']} "
                  f"ttl {np.mean(ep['time_to_localize_s']):.1f} s "
                  f"conflicts {ep['detection_conflicts']}", flush=True)
    out = summarize(episodes)
    out["cpu_s"] = time.process_time() - t0
    print(json.dumps(out), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"summary": out, "episodes": episodes, "seeds": seeds,
                       "policy": args.policy, "scenario": args.scenario,
                       "overrides": args.overrides}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
