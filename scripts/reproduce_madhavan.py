"""Reproduce the DGPS-outage experiment of Madhavan, Fregene and Parker (Fig. 4(b)).

Two robots drive east; robot 1 passes under a tree canopy and loses DGPS.
Its EKF position standard deviation grows during the outage and falls at each
laser-based cooperative update with robot 0. Prints the three figures, writes
them as JSON (``--json``, with the ``"profile"``) and saves the plot (``--plot``).

Example::

    python scripts/reproduce_madhavan.py --json outputs/madhavan.json \\
        --plot outputs/madhavan_fig4b.png
    python scripts/reproduce_madhavan.py --profile paper --json outputs/madhavan_paper.json

``--profile paper`` takes the laser-based relative measurement as the minimum of
the observer's laser profile (:mod:`coop_loc_env.profiles`).
"""

from __future__ import annotations

import sys
from pathlib import Path

from coop_loc_env.cli import ScriptParser, require, run_script
from coop_loc_env.profiles import PROFILES, with_profile
from policies.experiments.madhavan import plot_dgps_outage, run_dgps_outage
from policies.experiments.report import write_json
from policies.experiments.runner import parse_overrides

KEYS = ("std_before_outage_m", "std_peak_m", "std_after_first_coop_update_m")


def main(argv: list[str] | None = None) -> int:
    """Run the experiment; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=0, help="episode seed")
    p.add_argument("--duration", type=float, default=50.0, help="seconds to drive")
    p.add_argument("--json", type=Path, default=None, help="write the three figures here")
    p.add_argument("--plot", default="outputs/madhavan_fig4b.png",
                   help="where to save the plot ('' to skip)")
    p.add_argument("--profile", choices=PROFILES, default="default",
                   help="'paper': the laser-based relative measurement as the minimum of the "
                        "observer's laser profile (range and bearing only)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override of the dgps_outage scenario, repeatable")
    args = p.parse_args(argv)
    if args.plot:
        require("matplotlib")  # the plot comes after the runs: fail before them
    try:
        overrides = with_profile("dgps_outage", args.profile, parse_overrides(args.overrides))
        result = run_dgps_outage(args.seed, args.duration, **overrides)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    a, b = result["outage_s"]
    print(f"robot 1 without DGPS from t = {a:.1f} s to t = {b:.1f} s")
    inside = [t for t in result["coop_update_times_s"] if a < t <= b]
    print(f"laser-based cooperative updates during the outage at t = {inside} s")
    for key in KEYS:
        print(f"{key:32s} {result[key]:.3f}")
    if args.json is not None:
        write_json({"profile": args.profile, **{k: result[k] for k in KEYS}}, args.json)
        print(f"wrote {args.json}")
    if args.plot:
        print(f"wrote {plot_dgps_outage(result, Path(args.plot))}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
