"""Evaluate a policy on a scenario: a table of mean +/- std figures, JSON and plots.

Examples::

    python scripts/evaluate.py --scenario outdoor_terrain --policy fsm --episodes 3 \\
        --max-cycles 6000 --json outputs/eval.json --plot-dir outputs
    python scripts/evaluate.py --policy seek --episodes 5 --set n_robots=4 --set estimator=ekf
    python scripts/evaluate.py --policy models/ppo_coop.zip --episodes 10 --max-cycles 300
    python scripts/evaluate.py --compare fsm,random,runs/ppo/final_model.zip --episodes 20 \
        --plot-dir outputs --json outputs/compare.json

``--policy`` is a registered policy name (``--help`` lists them: ``fsm``,
``random``, ``seek``, ``still``, ``wander[:SPEED]``, ...) or the path of a
saved stable-baselines3 model (one network shared by all robots).
Episode ``k`` uses seed ``--seed + k``.
Figures: team localization error (mean over robots and steps of the position
error), final coverage of the drivable area by the team map, final map RMSE,
collisions and tip-overs. The JSON holds ``{"scenario", "policy", "episodes",
"summary"}``; the plots show error vs time per robot and the final terrain map
beside the true height field.

``--compare A,B,...`` runs every listed policy on the same seeds (20 episodes
unless ``--episodes`` says otherwise) and prints one table of means with 95 %
confidence intervals (plus the time to localize, spread < 1.5 m), saves a bar
plot ``SCENARIO_compare.png`` in ``--plot-dir`` (default ``outputs``; where time to
localize is reported, also ``SCENARIO_localized.png``, the fraction of robots localized
over time per policy, and the median time with a bootstrap interval) and the
report as JSON with ``--json`` (see :mod:`policies.experiments.compare`), and the paired
difference (same seeds) in time to localize of every other policy vs the
first listed one. Where every robot is localized from the first step (e.g. with
DGPS on ``outdoor_terrain``), the time to localize is left out.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from coop_loc_env.cli import (
    ScriptParser,
    add_config_arguments,
    require,
    run_script,
    scenario_and_overrides,
)
from policies.experiments.report import format_table, report, write_json
from policies.experiments.runner import run_episodes
from policies.scripted.registry import policy_help


def build_parser() -> argparse.ArgumentParser:
    """The command-line interface (other scripts may extend it)."""
    p = ScriptParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=f"policies (--policy, --compare), or the path of a saved stable-baselines3 "
               f"model (.zip):\n{policy_help()}",
    )
    add_config_arguments(p, "outdoor_terrain")
    p.add_argument("--policy", default="fsm",
                   help="a policy name (listed below), PATH.zip (SB3 model) or DIR (SB3 or "
                        "RLlib training run)")
    p.add_argument("--episodes", type=int, default=None,
                   help="number of episodes (default 3, or 20 with --compare)")
    p.add_argument("--compare", default=None, metavar="A,B,...",
                   help="compare policies, e.g. fsm,random,PATH.zip: one table with 95%% CIs "
                        "and a bar plot")
    p.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    p.add_argument("--max-cycles", type=int, default=None, help="steps per episode (override)")
    p.add_argument("--json", type=Path, default=None, help="write the report as JSON here")
    p.add_argument("--plot-dir", type=Path, default=None, help="write PNG plots here")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the evaluation; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.plot_dir is not None or args.compare is not None:
        require("matplotlib")  # the plots come at the end: fail before the episodes
    if not args.no_progress:
        require("tqdm")
    try:
        args.scenario, overrides = scenario_and_overrides(args)
        if args.max_cycles is not None:
            overrides["max_cycles"] = args.max_cycles
        if args.compare is not None:
            return _compare(args, overrides)
        if args.episodes is None:
            args.episodes = 3
        episodes = run_episodes(args.scenario, args.policy, args.episodes, args.seed, overrides,
                                progress=not args.no_progress)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    data = report(args.scenario, args.policy, episodes)
    print(f"scenario {args.scenario}, policy {args.policy}")
    print(format_table(data["summary"], len(episodes)))
    if args.json is not None:
        write_json(data, args.json)
        print(f"wrote {args.json}")
    if args.plot_dir is not None:
        from policies.experiments.plots import plot_errors, plot_terrain

        stem = f"{args.scenario}_{Path(args.policy).stem}"
        a = plot_errors(episodes, args.plot_dir / f"{stem}_error.png",
                        title=f"{args.scenario} / {args.policy}: position error per robot")
        last, summary, n = episodes[-1], data["summary"], len(episodes)
        b = plot_terrain(last, args.plot_dir / f"{stem}_terrain.png", title=(
            f"{args.scenario} / {args.policy}: episode seed {last['seed']} (the last of {n}), "
            f"final coverage {last['coverage']:.3f}, map RMSE {last['map_rmse_m']:.3f} m\n"
            f"mean over the {n} episode{'s' if n > 1 else ''}: coverage "
            f"{summary['coverage']['mean']:.3f}, map RMSE "
            f"{summary['map_rmse_m']['mean']:.3f} m"))
        print(f"wrote {a} and {b}")
    return 0


def _compare(args: argparse.Namespace, overrides: dict) -> int:
    """The ``--compare`` mode (raises ``ValueError`` on bad input)."""
    from coop_loc_env import make_config
    from policies.experiments.compare import (
        COMPARE_FIGURES,
        SPREAD_THRESHOLD,
        compare,
        format_compare_table,
        format_paired,
        localized_from_the_start,
        parse_policy_list,
        plot_compare,
        policy_label,
    )
    from policies.experiments.localization_curves import median_ci, plot_localized_curve

    specs = parse_policy_list(args.compare)
    n = 20 if args.episodes is None else args.episodes
    def save_partial(partial: dict) -> None:  # keep finished policies if cut short
        if args.json is not None and len(partial["policies"]) < len(specs):
            write_json(partial, args.json.with_suffix(".partial.json"))

    data = compare(args.scenario, specs, n, args.seed, overrides, progress=not args.no_progress,
                   on_policy_done=save_partial)
    table = COMPARE_FIGURES
    panels = ("localization_error_m", "coverage", "time_to_localize_s", "collisions")
    paired = "time_to_localize_s"
    if localized_from_the_start(data, make_config(args.scenario, **overrides).dt):
        table = tuple(f for f in table if f not in ("time_to_localize_s", "localized_fraction",
                                                     "localized_at_end"))
        panels = tuple(f for f in panels if f != "time_to_localize_s")
        paired = "localization_error_m"
        print(f"(time to localize left out: every robot's spread was below "
              f"{SPREAD_THRESHOLD} m from the first step)")
    print(format_compare_table(data, table))
    if paired == "time_to_localize_s":
        print("median time to localize (s) [95 % bootstrap CI]: " + ", ".join(
            "{}: {:.4g} [{:.4g}, {:.4g}]".format(policy_label(spec), *median_ci(
                [r["time_to_localize_s"] for r in data["episodes"][spec]]))
            for spec in specs))
    if len(specs) > 1 and n > 1:
        print(format_paired(data, specs[0], paired))
    if n < 20:
        print(f"note: {n} episodes; use >= 20 episodes for 95 % intervals you can trust")
    if args.json is not None:
        write_json(data, args.json)
        args.json.with_suffix(".partial.json").unlink(missing_ok=True)  # superseded
        print(f"wrote {args.json}")
    plot_dir = args.plot_dir if args.plot_dir is not None else Path("outputs")
    print(f"wrote {plot_compare(data, plot_dir / f'{args.scenario}_compare.png', panels)}")
    if paired == "time_to_localize_s":
        curve = plot_localized_curve(data, plot_dir / f"{args.scenario}_localized.png",
                                     make_config(args.scenario, **overrides).dt)
        print(f"wrote {curve}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
