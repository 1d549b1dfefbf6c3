"""Markdown table comparing two trees' ``recovery_stress.py --json`` outputs. Prints it.

Rows group the cases of one window, one kind (``clean``, ``biased_landmark`` ...,
``kidnapped``) and one estimator; each gives, before and after, the mean position error
averaged over the group's cases, the mean NEES95, the recoveries summed, and the worst
robot's RMSE and RMSE-to-mean ratio among them (kidnapped cases: the slowest seconds to
0.5 m after the first landmark reading instead of the ratio).

    python scripts/bench/recovery_table.py before.json after.json [more_before.json ...]
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict

from coop_loc_env.cli import ScriptParser, run_script


def _groups(cases: dict) -> dict[tuple[str, str, str], list[dict]]:
    """Cases keyed ``"START:DUR CASE [ARG] ESTIMATOR"`` grouped by (window, case, estimator)."""
    out: dict[tuple[str, str, str], list[dict]] = defaultdict(list)
    for key, fig in cases.items():
        parts = key.split()
        out[(parts[0], parts[1], parts[-1])].append(fig)
    return out


def _summary(figs: list[dict]) -> dict:
    robots = [r for f in figs for r in f["per_robot"].values()]
    kid = [f.get("seconds_to_0.5m_after_first_landmark", 0.0) for f in figs
           if "kidnapped_robot" in f]
    return {
        "mean": sum(f["mean_position_error_m"] for f in figs) / len(figs),
        "nees": sum(f["nees_95_fraction"] for f in figs) / len(figs),
        "rec": sum(f["recoveries"] or 0 for f in figs),
        "rmse": max(r[1] for r in robots),
        "ratio": max(r[1] / r[0] for r in robots if r[0] > 0),
        "kidnapped": bool(kid),
        "slowest": None if None in kid else max(kid, default=0.0),
    }


def table(before: dict, after: dict) -> str:
    """The markdown table of the groups present in both."""
    b, a = _groups(before), _groups(after)
    lines = [
        "| window | case | estimator | cases | mean error before [m] | after | NEES95 before "
        "| after | recoveries before | after | worst robot RMSE before [m] | after "
        "| worst RMSE/mean (kidnapped: slowest s to 0.5 m) before | after |",
        "|" + "---|" * 14,
    ]
    for key in sorted(set(b) & set(a), key=lambda k: (float(k[0].split(":")[0]), k[1], k[2])):
        sb, sa = _summary(b[key]), _summary(a[key])
        last = ("slowest", "{}") if sb["kidnapped"] else ("ratio", "{:.2f}")

        def fmt(s: dict, name: str = last[0], spec: str = last[1]) -> str:
            return "never" if s[name] is None else spec.format(s[name])

        lines.append(
            f"| {key[0]} | {key[1]} | `{key[2]}` | {len(b[key])} | {sb['mean']:.3f} "
            f"| {sa['mean']:.3f} | {sb['nees']:.2f} | {sa['nees']:.2f} | {sb['rec']} "
            f"| {sa['rec']} | {sb['rmse']:.2f} | {sa['rmse']:.2f} | {fmt(sb)} | {fmt(sa)} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = ScriptParser(description=__doc__.splitlines()[0])
    p.add_argument("pairs", nargs="+", help="BEFORE.json AFTER.json, one pair or more")
    args = p.parse_args(argv)
    if len(args.pairs) % 2:
        print("give the JSON files in BEFORE AFTER pairs", file=sys.stderr)
        return 2
    try:
        runs = [json.loads(open(path).read()) for path in args.pairs]
    except (OSError, ValueError) as err:
        print(f"cannot read a JSON file: {err}", file=sys.stderr)
        return 2
    for k in range(0, len(runs), 2):
        print(table(runs[k], runs[k + 1]))
        print()
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
