"""Evaluate scripted policies on a scenario and print mean figures over seeded episodes.

    python examples/evaluate.py [--scenario outdoor_terrain] [--episodes 2]

The same as ``scripts/evaluate.py --policy NAME`` (which adds JSON, plots and
``--compare`` with confidence intervals), written out with the library calls.
"""

from __future__ import annotations

import argparse

from policies.experiments.report import format_table, summarize
from policies.experiments.runner import run_episodes


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="outdoor_terrain")
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--max-cycles", type=int, default=100)
    args = p.parse_args(argv)
    for policy in ("fsm", "random", "still"):
        episodes = run_episodes(args.scenario, policy, args.episodes, seed=0,
                                overrides={"max_cycles": args.max_cycles}, progress=False)
        print(f"\n{args.scenario} / {policy}")
        print(format_table(summarize(episodes), len(episodes)))


if __name__ == "__main__":
    main()
