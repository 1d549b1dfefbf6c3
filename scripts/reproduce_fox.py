"""Reproduce the collaborative-MCL experiments of Fox, Burgard, Kruppa and Thrun.

``hallway`` (Fig. 12): eight sonar robots localize globally in the
``symmetric_hallway`` scenario, with and without robot detections, over
``--seeds`` seeds. Prints per condition the mean +/- std time (simulated
seconds) for a robot to bring its ``particle_spread`` below 1.5 m (robots that
never do count at the time limit; how many is printed), the % reduction, and
saves an error-vs-time plot. The paper: 379 +/- 37 s alone, 153 +/- 17 s with
detections (-60 %).

``hexagon`` (Figs. 13-14): four sonar and four laser robots in the symmetric
``hexagon``; reports per sensor type how many robots are localized (spread
below 1.5 m) at the end, throughout the last 60 s, and ever, with and without
detections, and saves the error-vs-time plot per sensor type (Fig. 14). The
paper: neither sensor type alone localizes (the error stays high); with
detections every robot does. The time figures printed for it count a robot
alone as "localized" when it merely passes near the centre, where its
symmetric copies are close together (see ``run_hexagon_experiment``).

``--profile paper`` runs the paper's method alone (:mod:`coop_loc_env.profiles`):
its detector as its simulation drew it (line of sight, 1 Hz, mean errors 48.3 cm
and 2.2 degrees, range and bearing only, no false positives), a few uniform
random particles after every estimation step, no sensor resetting. The JSON
records the profile.

Examples::

    python scripts/reproduce_fox.py --json outputs/fox.json
    python scripts/reproduce_fox.py --experiment hexagon --seeds 4
    python scripts/reproduce_fox.py --profile paper --experiment hallway \\
        --json outputs/fox_paper.json
"""

from __future__ import annotations

import sys
from pathlib import Path

from coop_loc_env.cli import ScriptParser, require, run_script
from coop_loc_env.profiles import PROFILES, with_profile
from policies.experiments.fox import (
    CONDITIONS,
    plot_error_vs_time,
    run_hallway_experiment,
    run_hexagon_experiment,
)
from policies.experiments.report import write_json
from policies.experiments.runner import parse_overrides

KEYS = ("mean_s", "std_s", "not_localized")


def _print_times(name: str, result: dict) -> None:
    print(f"\n{name}: time to bring particle_spread below 1.5 m (simulated s)")
    for cond in CONDITIONS:
        r = result[cond]
        print(f"  {cond:20s} {r['mean_s']:7.1f} +/- {r['std_s']:5.1f} s   "
              f"({r['not_localized']} of {r['robots']} robots never localized, counted at the "
              f"time limit)")
    lo, hi = result["reduction_ci95_pct"]
    print(f"  reduction with detections: {result['reduction_pct']:.1f} % "
          f"(95 % bootstrap interval over seeds {lo:.1f} to {hi:.1f} %)")


def _print_hexagon(result: dict) -> None:
    print("  per sensor type, robots localized (spread < 1.5 m) at the end / throughout the "
          "last 60 s / ever, of all; mean final spread:")
    for sensor, conds in result["by_sensor"].items():
        for cond in CONDITIONS:
            r = conds[cond]
            lo, hi = r["localized_at_end_ci95"]
            print(f"  {sensor:6s} {cond:20s} {r['localized_at_end']:3d} / "
                  f"{r['localized_last_60s']:3d} / {r['ever_localized']:3d} of {r['robots']}"
                  f"   final spread {r['mean_final_spread_m']:5.2f} m   at end "
                  f"{100 * lo:.0f}-{100 * hi:.0f} % (95 % over seeds)")


def main(argv: list[str] | None = None) -> int:
    """Run the experiments; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--experiment", choices=("hallway", "hexagon", "all"), default="all")
    p.add_argument("--seeds", type=int, default=8, help="episodes per condition (hallway)")
    p.add_argument("--hexagon-seeds", type=int, default=4, help="episodes per condition (hexagon)")
    p.add_argument("--first-seed", type=int, default=0,
                   help="seeds are FIRST_SEED, FIRST_SEED + 1, ... (default 0)")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated seconds per episode (default: the scenario's max_cycles)")
    p.add_argument("--json", type=Path, default=None, help="write the figures here")
    p.add_argument("--plot-dir", type=str, default="outputs",
                   help="where to save the error-vs-time plots ('' to skip)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--profile", choices=PROFILES, default="default",
                   help="'paper': the paper's simulated detector (line of sight, 1 Hz, its "
                        "error figures, range and bearing only, no false positives), uniform "
                        "random particles after every step, no sensor resetting")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override of the scenarios, repeatable (e.g. n_particles=1000)")
    args = p.parse_args(argv)
    if args.plot_dir:
        require("matplotlib")  # the plot comes after the runs: fail before them
    if not args.no_progress:
        require("tqdm")
    if args.seeds < 1 or args.hexagon_seeds < 1:
        print(f"error: --seeds and --hexagon-seeds must be >= 1, got {args.seeds}, "
              f"{args.hexagon_seeds}", file=sys.stderr)
        return 2
    try:
        user = parse_overrides(args.overrides)
        out: dict = {"profile": args.profile}
        suffix = "" if args.profile == "default" else f"_{args.profile}"
        if args.experiment in ("hallway", "all"):
            overrides = with_profile("symmetric_hallway", args.profile, user)
            res = run_hallway_experiment(range(args.first_seed, args.first_seed + args.seeds),
                                         args.duration,
                                         not args.no_progress, **overrides)
            _print_times("hallway", res)
            out["hallway"] = {
                **{c: {k: res[c][k] for k in KEYS} for c in CONDITIONS},
                "reduction_pct": res["reduction_pct"],
                "reduction_ci95_pct": res["reduction_ci95_pct"],
                "per_seed_mean_s": res["per_seed_mean_s"],
            }
            if args.plot_dir:
                path = plot_error_vs_time(res["curves"],
                                          Path(args.plot_dir) / f"fox_hallway{suffix}.png",
                                          "symmetric hallway: mean particle spread, 8 robots")
                print(f"  wrote {path}")
        if args.experiment in ("hexagon", "all"):
            overrides = with_profile("hexagon", args.profile, user)
            res = run_hexagon_experiment(
                range(args.first_seed, args.first_seed + args.hexagon_seeds), args.duration,
                                         not args.no_progress, **overrides)
            _print_times("hexagon", res)
            _print_hexagon(res)
            out["hexagon"] = {
                **{c: {k: res[c][k] for k in KEYS} for c in CONDITIONS},
                "reduction_pct": res["reduction_pct"],
                "reduction_ci95_pct": res["reduction_ci95_pct"],
                "per_seed_mean_s": res["per_seed_mean_s"],
                "by_sensor": res["by_sensor"],
            }
            if args.plot_dir:
                path = plot_error_vs_time(res["curves"],
                                          Path(args.plot_dir) / f"fox_hexagon{suffix}.png",
                                          "hexagon: mean particle spread per sensor type")
                print(f"  wrote {path}")
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.json is not None:
        write_json(out, args.json)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
