"""Plot the true paths of a team under several policies on one seeded episode, side by side.

Example::

    python scripts/plot_trajectories.py --scenario rendezvous --policies gather,infogain \\
        --seed 1000 --set layout_seed=11 --out docs/figures/rendezvous_trajectories.png

Each panel shows the walls (grey), the tree canopies (where DGPS fails, green),
the robots' true paths (robots with GPS in blue, without in orange; a circle
marks the start, a cross the end) and the episode's team localization error
in its title.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import coop_loc_env
from coop_loc_env.cli import ScriptParser, require, run_script
from policies.episode import env_overrides_for, run_episode
from policies.experiments.compare import parse_policy_list, policy_label, resolve_policy
from policies.experiments.runner import parse_overrides


def record_paths(scenario: str, spec: str, seed: int, overrides: dict) -> tuple[np.ndarray, dict]:
    """``(steps + 1, n, 3)`` true poses of one episode of policy ``spec``, and its record."""
    policy = resolve_policy(spec)
    env = coop_loc_env.parallel_env(scenario, **env_overrides_for(policy, overrides))
    poses: list[np.ndarray] = []
    try:
        ep = run_episode(env, policy, seed,
                         on_step=lambda e, _i: poses.append(e.world.poses.copy()),
                         on_reset=lambda e: poses.append(e.world.poses.copy()))
        ep["layout"] = env.world.layout
        ep["gps"] = [env.config.robot_spec(i).has_gps for i in range(env.config.n_robots)]
        ep["world_size"] = env.config.world_size
    finally:
        env.close()
    return np.array(poses), ep


def main(argv: list[str] | None = None) -> int:
    """Run the episodes and write the figure; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="rendezvous")
    p.add_argument("--policies", required=True, metavar="A,B,...")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    require("matplotlib")
    try:
        specs = parse_policy_list(args.policies)
        overrides = parse_overrides(args.overrides)
        runs = [record_paths(args.scenario, s, args.seed, overrides) for s in specs]
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(runs), figsize=(4.6 * len(runs), 4.6), squeeze=False)
    for ax, spec, (paths, ep) in zip(axes[0], specs, runs, strict=True):
        layout = ep["layout"]
        for obstacle in layout.obstacles:
            if obstacle.shape == "polygon" and obstacle.solid:
                ax.add_patch(plt.Polygon(obstacle.vertices, color="grey", alpha=0.5, lw=0))
        for c, r in zip(layout.canopy_centers, layout.canopy_radii, strict=True):
            ax.add_patch(plt.Circle(c, r, color="green", alpha=0.25, lw=0))
        for i, gps in enumerate(ep["gps"]):
            color = "tab:blue" if gps else "tab:orange"
            ax.plot(paths[:, i, 0], paths[:, i, 1], color=color, lw=1.5)
            ax.plot(*paths[0, i, :2], "o", color=color)
            ax.plot(*paths[-1, i, :2], "x", color=color, ms=8, mew=2)
        w, h = ep["world_size"]
        ax.set(xlim=(0, w), ylim=(0, h), aspect="equal", xlabel="x (m)", ylabel="y (m)",
               title=f"{policy_label(spec)}: team error {ep['localization_error_m']:.2f} m")
    _, ep = runs[0]
    legend = ["blue: GPS" if any(ep["gps"]) else "", "orange: no GPS" if not all(ep["gps"]) else "",
              "green: canopy" if len(ep["layout"].canopy_radii) else "", "grey: walls"]
    fig.suptitle(f"{args.scenario}, seed {args.seed} ({', '.join(t for t in legend if t)})",
                 fontsize=9)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
