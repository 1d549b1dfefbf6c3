"""Run one short episode with random actions, print each robot's localization error,
and save a rendered frame.

    python scripts/run_episode.py --scenario outdoor_terrain --steps 100 --frame outputs/frame.png
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import coop_loc_env


def run(scenario: str, steps: int, seed: int, frame: Path | None) -> dict[str, float]:
    """Run ``steps`` random-action steps; returns the mean position error per robot."""
    env = coop_loc_env.parallel_env(scenario, max_cycles=steps,
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
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="outdoor_terrain",
                        choices=coop_loc_env.list_scenarios())
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frame", type=Path, default=Path("outputs/frame.png"))
    args = parser.parse_args(argv)
    try:
        errors = run(args.scenario, args.steps, args.seed, args.frame)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{args.scenario}: {args.steps} steps, seed {args.seed}")
    for agent, err in errors.items():
        print(f"  {agent}: mean position error {err:.3f} m")
    print(f"frame saved to {args.frame}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
