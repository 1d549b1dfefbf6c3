"""Save a GIF of one episode of a policy on a scenario.

Example::

    python scripts/render_episode.py --scenario outdoor_terrain --policy fsm \\
        --max-cycles 300 --out outputs/episode.gif
    python scripts/render_episode.py --config examples/configs/mixed_team.yaml --policy seek \\
        --max-cycles 100 --out outputs/mixed.gif

``--config FILE.yaml`` holds the scenario, any scenario config key and the team
(see docs/configs.md); ``--set`` and ``--scenario`` apply on top of it.
"""

from __future__ import annotations

import sys
from pathlib import Path

from coop_loc_env.cli import (
    ScriptParser,
    add_config_arguments,
    require,
    run_script,
    scenario_and_overrides,
)
from policies.experiments.runner import record_frames
from policies.scripted.registry import policy_names


def main(argv: list[str] | None = None) -> int:
    """Render the episode; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    add_config_arguments(p, "outdoor_terrain")
    p.add_argument("--policy", default="fsm",
                   help=f"{' | '.join(policy_names())} | PATH.zip (SB3 model)")
    p.add_argument("--seed", type=int, default=0, help="episode seed")
    p.add_argument("--max-cycles", type=int, default=None, help="steps (override)")
    p.add_argument("--every", type=int, default=5, help="keep one frame every N steps")
    p.add_argument("--fps", type=float, default=10.0, help="GIF frame rate")
    p.add_argument("--out", type=Path, default=Path("outputs/episode.gif"), help="GIF path")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    args = p.parse_args(argv)
    require("imageio", *(() if args.no_progress else ("tqdm",)))
    try:
        args.scenario, overrides = scenario_and_overrides(args)
        if args.max_cycles is not None:
            overrides["max_cycles"] = args.max_cycles
        frames, ep = record_frames(args.scenario, args.policy, args.seed, overrides, args.every,
                                   progress=not args.no_progress)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    import imageio.v2 as imageio

    args.out.parent.mkdir(parents=True, exist_ok=True)
    imageio.mimsave(args.out, frames, duration=1.0 / args.fps, loop=0)
    print(f"wrote {args.out}: {len(frames)} frames of {ep['steps']} steps; "
          f"localization error {ep['localization_error_m']:.3f} m, "
          f"coverage {ep['coverage']:.3f}, collisions {ep['collisions']}, "
          f"tip-overs {ep['tip_overs']}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
