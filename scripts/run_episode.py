"""Run one short episode with random actions, print each robot's localization error,
and save a rendered frame.

    python scripts/run_episode.py --scenario outdoor_terrain --steps 100 --frame outputs/frame.png
    python scripts/run_episode.py --config examples/configs/mixed_team.yaml --steps 50

``--config FILE.yaml`` holds the scenario, any scenario config key and the team
(see docs/configs.md); ``--set KEY=VALUE`` applies on top of it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import coop_loc_env
from coop_loc_env.cli import (
    ScriptParser,
    add_config_arguments,
    require,
    run_script,
    scenario_and_overrides,
)


def run(scenario: str, steps: int, seed: int, frame: Path | None,
        overrides: dict | None = None) -> dict[str, float]:
    """Run ``steps`` random-action steps; returns the mean position error per robot."""
    env = coop_loc_env.parallel_env(scenario, **{**(overrides or {}), "max_cycles": steps},
                                    render_mode="rgb_array" if frame else None)
    env.reset(seed=seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(seed + env.agent_name_mapping[agent])
    errors: dict[str, list[float]] = {a: [] for a in env.possible_agents}
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        _, _, _, _, infos = env.step(actions)
        for agent, info in infos.items():
            errors[agent].append(info["position_error"])
    if frame:
        import imageio.v2 as imageio

        frame.parent.mkdir(parents=True, exist_ok=True)
        imageio.imwrite(frame, env.render())
    env.close()
    return {a: float(np.mean(e)) for a, e in errors.items()}


def main(argv: list[str] | None = None) -> int:
    """Run the episode and print the errors; returns the exit status."""
    parser = ScriptParser(description=__doc__,
                          formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_arguments(parser, "outdoor_terrain")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frame", type=Path, default=Path("outputs/frame.png"))
    args = parser.parse_args(argv)
    if args.frame:
        require("imageio", "matplotlib")  # the frame is drawn with matplotlib, saved by imageio
    try:
        args.scenario, overrides = scenario_and_overrides(args)
        errors = run(args.scenario, args.steps, args.seed, args.frame, overrides)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{args.scenario}: {args.steps} steps, seed {args.seed}")
    for agent, err in errors.items():
        print(f"  {agent}: mean position error {err:.3f} m")
    print(f"frame saved to {args.frame}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
