"""The lattice oracle: a reference that knows the true poses and the bay, for ``active_lattice``.

Not a baseline (it reads the truth, which no policy may): it bounds what choosing
where to drive can buy on a symmetric lattice. Every robot drives the shortest path
to the bay from its TRUE pose (so the nearest gets there first), and once it has
passed within ``AT_BAY_M`` of it, follows the corridors (as ``corridor``), which keeps
the team from crowding the bay. Everything else -- the estimator, detections, the time-to-localize
measure -- is the scenario's. It runs next to the policies given, on the same seeds
(the same maps), and prints the comparison table and the paired differences, like
``scripts/evaluate.py --compare``::

    python scripts/bench/lattice_oracle.py --episodes 40 --seed 300000 \\
        --compare corridor,hypothesis,split
    python scripts/bench/lattice_oracle.py --set lattice_size=7 --set decoys=2
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from coop_loc_env.scenarios import make_config
from estimators.geometry import wrap_angle
from policies.experiments.compare import (
    compare,
    format_compare_table,
    format_paired,
    mean_ci,
    parse_policy_list,
)
from policies.experiments.report import write_json
from policies.experiments.runner import parse_overrides
from policies.scripted.corridor import CorridorPolicy, follow
from policies.scripted.hypothesis import plan_grid, toward
from policies.scripted.registry import register_policy

ORACLE = "lattice_oracle"
ACCURACY_AT_S = 30.0  # s: the horizon of the accuracy figure
#: the ratios the headroom is judged by: (policy, against)
HEADROOM_PAIRS = ((ORACLE, "corridor"), ("hypothesis", "corridor"), ("split", "hypothesis"),
                  ("split", "corridor"))
AT_BAY_M = 1.0  # m: a robot this near the bay's centre has been there
LOOKAHEAD_M = 1.5  # m along the path of the point steered to


class LatticeOraclePolicy(CorridorPolicy):
    """Every robot drives to the true bay, then follows the corridors (module doc)."""

    name = ORACLE

    def reset(self, env, seed: int | None = None) -> None:
        super().reset(env, seed)
        lattice = getattr(env, "lattice", None)
        if lattice is None:
            raise ValueError(f"{ORACLE} needs the active_lattice scenario, got {env.scenario!r}")
        grid = env.backends[0].particle_filter(0).grid
        cfg = env.config
        self.plan = plan_grid(grid, cfg.world_size, cfg.robot_radius + 0.25)
        self.bay_cell = int(self.plan.cell_of(np.asarray(lattice.bay)))
        self.bay_tree = self.plan.distances(self.bay_cell)[1]
        self.been = np.zeros(cfg.n_robots, dtype=bool)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        poses = self.env.world.poses  # the truth: a reference, not a policy
        index = self.env.agent_name_mapping
        bay = self.plan.centres[self.bay_cell]
        out = {}
        for agent in self.env.agents:
            i = index[agent]
            self.been[i] |= math.hypot(*(poses[i, :2] - bay)) < AT_BAY_M
            if self.been[i]:
                out[agent] = follow(self._view(i), self.speed, self.gain)
            else:
                out[agent] = self._drive(i, poses[i], self.bay_tree)
        return out

    def _drive(self, i: int, pose: np.ndarray, tree: np.ndarray) -> np.ndarray:
        plan = self.plan
        cell = int(plan.cell_of(pose[:2]))
        point, prev, walked = plan.centres[cell], plan.centres[cell], 0.0
        for _ in range(int(LOOKAHEAD_M / plan.cell) * 2 + 2):
            nxt = int(tree[cell])
            if nxt < 0:
                break
            walked += float(np.hypot(*(plan.centres[nxt] - prev)))
            prev, cell, point = plan.centres[nxt], nxt, plan.centres[nxt]
            if walked >= LOOKAHEAD_M:
                break
        d = point - pose[:2]
        if not np.any(d):
            return np.zeros(2, dtype=np.float32)
        err = float(wrap_angle(math.atan2(d[1], d[0]) - pose[2]))
        return toward(self._view(i), err, self.speed)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="active_lattice")
    p.add_argument("--episodes", type=int, default=40)
    p.add_argument("--seed", type=int, default=300_000)
    p.add_argument("--compare", default="corridor", metavar="A,B,...",
                   help="policies run beside the oracle on the same seeds")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--plot-dir", type=Path, default=None,
                   help="write the localized-over-time curve here")
    args = p.parse_args(argv)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        if args.scenario != "active_lattice":
            raise ValueError(f"--scenario must be active_lattice, got {args.scenario!r}")
        register_oracle()
        specs = [ORACLE, *parse_policy_list(args.compare)]
        data = compare(args.scenario, specs, args.episodes, args.seed,
                       parse_overrides(args.overrides), progress=False)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(format_compare_table(data, ("time_to_localize_s", "localized_fraction",
                                      "localized_at_end", "collisions")))
    print(format_paired(data, ORACLE))
    print(format_headroom(data))
    if args.plot_dir is not None:
        from policies.experiments.localization_curves import plot_localized_curve

        args.plot_dir.mkdir(parents=True, exist_ok=True)
        dt = make_config(args.scenario, **parse_overrides(args.overrides)).dt
        path = args.plot_dir / "active_lattice_localized.png"
        print(f"wrote {plot_localized_curve(data, path, dt)}")
    if args.json is not None:
        write_json(data, args.json)
        print(f"wrote {args.json}")
    return 0


def paired_ratio(report: dict, a: str, b: str, n_boot: int = 4000, seed: int = 0
                 ) -> tuple[float, float, float]:
    """``(ratio, low, high)``: mean time to localize of ``a`` over ``b``'s on the same
    episodes, with a 95 % bootstrap interval resampling the episode pairs."""
    ta = np.array([r["time_to_localize_s"] for r in report["episodes"][a]], dtype=float)
    tb = np.array([r["time_to_localize_s"] for r in report["episodes"][b]], dtype=float)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(ta), (n_boot, len(ta)))
    boots = ta[idx].mean(axis=1) / tb[idx].mean(axis=1)
    return float(ta.mean() / tb.mean()), *(float(q) for q in np.quantile(boots, [0.025, 0.975]))


def accuracy_at(report: dict, spec: str, seconds: float = ACCURACY_AT_S
                ) -> tuple[float, float, float]:
    """``(mean, low, high)``: the fraction of a policy's robots localized by ``seconds``
    (per episode, then the mean over episodes with its 95 % Student-t interval)."""
    per = [float(np.mean(np.asarray(r["robot_localized"], bool)
                         & (np.asarray(r["robot_times_to_localize_s"], float) <= seconds)))
           for r in report["episodes"][spec]]
    return mean_ci(np.array(per), bounds=(0.0, 1.0))


def format_headroom(report: dict) -> str:
    """Ratios of the mean times to localize (paired bootstrap intervals) of every pair in
    :data:`HEADROOM_PAIRS` present, and each policy's accuracy at ``ACCURACY_AT_S``."""
    specs = report["policies"]
    lines = [f"localized by {ACCURACY_AT_S:g} s (mean [95 % CI] over episodes):"]
    for spec in specs:
        m, lo, hi = accuracy_at(report, spec)
        lines.append(f"  {spec}: {m:.3f} [{lo:.3f}, {hi:.3f}]")
    lines.append("mean time to localize, ratio (paired bootstrap 95 % CI):")
    for a, b in HEADROOM_PAIRS:
        if a in specs and b in specs:
            r, lo, hi = paired_ratio(report, a, b)
            lines.append(f"  {a} / {b}: {r:.3f} [{lo:.3f}, {hi:.3f}]")
    return "\n".join(lines)


def register_oracle() -> None:
    """Register ``lattice_oracle`` as a policy name (once), for ``compare`` and
    ``scripts/evaluate.py`` run from this module."""
    from policies.scripted.registry import policy_names

    if ORACLE not in policy_names():
        register_policy(ORACLE, lambda _arg: LatticeOraclePolicy(1.0),
                        "drives the nearest robot to the true bay (reference: reads the truth)")


if __name__ == "__main__":
    sys.exit(main())
