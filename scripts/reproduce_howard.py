"""Reproduce the experiments of Howard, Mataric and Sukhatme (team localization by MLE).

* ``dispersal``: 20 robots start crowded in one room of a building and spread
  out; the team's mean relative range error (their Eq. 15) against time.
  Expected: lowest while crowded, growing as they spread.
* ``circuit``: six stationary robots out of each other's sight; a seventh
  drives a loop past each of them and back to the first. Expected: the error
  drops at each sighting, and sharply when the loop is closed.

Both run the centralized MLE (``estimator="mle"``), its gauge fixed by
anchoring one robot. Prints the figures, writes ``--json`` (``{"profile",
"anchoring", "dispersal": {"times_s", "range_error_m"}, "circuit": {"times_s",
"range_error_m", "closure_time_s", "error_before_closure_m",
"error_after_closure_m"}}``) and saves the plot (``--plot``). ``--profile paper``
solves the whole pose graph at every step, with every observation on nodes at
its own time and no validation gate (:mod:`coop_loc_env.profiles`).

Example::

    OPENBLAS_NUM_THREADS=1 python scripts/reproduce_howard.py \\
        --json outputs/howard.json --plot outputs/howard.png
    OPENBLAS_NUM_THREADS=1 python scripts/reproduce_howard.py --profile paper \\
        --json outputs/howard_paper.json --plot outputs/howard_paper.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from coop_loc_env import make_config
from coop_loc_env.backends.mle import ANCHORING
from coop_loc_env.cli import ScriptParser, require, run_script
from coop_loc_env.profiles import PROFILES, with_profile
from policies.experiments.howard import plot_howard, run_circuit, run_dispersal
from policies.experiments.report import write_json
from policies.experiments.runner import parse_overrides

EXPERIMENTS = ("dispersal", "circuit")


def _progress_bar(total: int, enabled: bool):
    """A tqdm bar (a no-op when disabled or tqdm is missing); returns ``(update, close)``."""
    if enabled:
        try:
            from tqdm import tqdm
        except ImportError:  # pragma: no cover - tqdm ships with the dev extras
            tqdm = None
        if tqdm is not None:
            bar = tqdm(total=total, unit="step", desc="howard")
            return bar.update, bar.close
    return None, lambda: None


def main(argv: list[str] | None = None) -> int:
    """Run the experiments; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=0, help="episode seed")
    p.add_argument("--experiments", nargs="+", choices=EXPERIMENTS, default=list(EXPERIMENTS),
                   help="which experiments to run")
    p.add_argument("--dispersal-duration", type=float, default=120.0, help="seconds")
    p.add_argument("--circuit-duration", type=float, default=175.0, help="seconds")
    p.add_argument("--json", type=Path, default=None, help="write the curves and figures here")
    p.add_argument("--plot", default="outputs/howard.png",
                   help="where to save the plot ('' to skip)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--profile", choices=PROFILES, default="default",
                   help="'paper': whole-graph solve at every step, no validation gate")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="config override applied to both scenarios, repeatable")
    args = p.parse_args(argv)
    if args.plot:
        require("matplotlib")  # the plot comes after the runs: fail before them
    if not args.no_progress:
        require("tqdm")
    total = 0
    try:
        user = parse_overrides(args.overrides)
        overrides = {name: with_profile(name, args.profile, user) for name in EXPERIMENTS}
        for name, seconds in (("dispersal", args.dispersal_duration),
                              ("circuit", args.circuit_duration)):
            if name in args.experiments:
                total += int(round(seconds / make_config(name, **overrides[name]).dt))
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    update, close = _progress_bar(total, not args.no_progress)
    out: dict = {"profile": args.profile, "anchoring": ANCHORING}
    results: dict[str, dict] = {}
    try:
        if "dispersal" in args.experiments:
            d = run_dispersal(args.seed, args.dispersal_duration, update,
                              **overrides["dispersal"])
            results["dispersal"] = d
            out["dispersal"] = {"times_s": d["times_s"].tolist(),
                                "range_error_m": d["range_error_m"].tolist()}
        if "circuit" in args.experiments:
            c = run_circuit(args.seed, args.circuit_duration, update, **overrides["circuit"])
            results["circuit"] = c
            out["circuit"] = {
                "times_s": c["times_s"].tolist(),
                "range_error_m": c["range_error_m"].tolist(),
                "closure_time_s": c["closure_time_s"],
                "error_before_closure_m": c["error_before_closure_m"],
                "error_after_closure_m": c["error_after_closure_m"],
            }
    except ValueError as err:
        close()
        print(f"error: {err}", file=sys.stderr)
        return 2
    close()
    if "dispersal" in results:
        d = results["dispersal"]
        t, e, spread = d["times_s"], d["range_error_m"], d["mean_distance_m"]
        print("dispersal: mean relative range error (m) and mean distance between robots (m)")
        for lo in np.arange(0.0, t[-1], 20.0):
            sel = (t > lo) & (t <= lo + 20.0)
            print(f"  t = {lo:5.0f}-{lo + 20:3.0f} s   error {e[sel].mean():.3f}   "
                  f"distance {spread[sel].mean():5.2f}")
    if "circuit" in results:
        c = results["circuit"]
        print("circuit: first sightings of each stationary robot by the driver (s): "
              + ", ".join(f"{r}: {ts:.1f}" for r, ts in c["sightings_s"].items()))
        print(f"  loop closure at t = {c['closure_time_s']:.1f} s: range error "
              f"{c['error_before_closure_m']:.3f} m before, {c['error_after_closure_m']:.3f} m "
              "after")
    if args.json is not None:
        write_json(out, args.json)
        print(f"wrote {args.json}")
    if args.plot:
        plot = Path(args.plot)
        print(f"wrote {plot_howard(results.get('dispersal'), results.get('circuit'), plot)}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
