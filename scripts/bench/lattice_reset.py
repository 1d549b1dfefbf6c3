"""Cost of an ``active_lattice`` reset: a new map every episode vs the same map again.

Example::

    python scripts/bench/lattice_reset.py --resets 20
    python scripts/bench/lattice_reset.py --set lattice_size=7 --set decoys=2

A new map builds its world, sensors, MCL grid, compiled range table and symmetries,
team mapper and observation tables; the same map (``map_seed`` fixed) reuses them and
only places the team and the particles. The two kinds of reset alternate, so both
see the same load. Prints milliseconds per reset (median and mean), of wall-clock time
and of this process's CPU time (the figure that holds on a shared, loaded machine).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import coop_loc_env
from policies.experiments.runner import parse_overrides


def bench(resets: int, overrides: dict) -> dict[str, np.ndarray]:
    """Seconds per reset, ``{"new map": ..., "same map": ...}`` (wall clock) and the same
    keys with `` cpu`` (process time), ``resets`` of each."""
    fresh = coop_loc_env.parallel_env("active_lattice", **overrides)
    fixed = coop_loc_env.parallel_env("active_lattice", **{"map_seed": 0, **overrides})
    fresh.reset(seed=0)  # compile and load everything once
    fixed.reset(seed=0)
    out: dict[str, list[float]] = {"new map": [], "same map": [], "new map cpu": [],
                                   "same map cpu": []}
    for k in range(1, resets + 1):
        for name, env in (("new map", fresh), ("same map", fixed)):
            t0, c0 = time.perf_counter(), time.process_time()
            env.reset(seed=k)
            out[name].append(time.perf_counter() - t0)
            out[name + " cpu"].append(time.process_time() - c0)
    return {k: np.array(v) for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--resets", type=int, default=20)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = p.parse_args(argv)
    try:
        if args.resets < 1:
            raise ValueError(f"--resets must be >= 1, got {args.resets}")
        times = bench(args.resets, parse_overrides(args.overrides))
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for name, t in times.items():
        print(f"{name:>12}: {1000 * np.median(t):7.1f} ms median, {1000 * t.mean():7.1f} ms mean "
              f"over {len(t)} resets")
    return 0


if __name__ == "__main__":
    sys.exit(main())
