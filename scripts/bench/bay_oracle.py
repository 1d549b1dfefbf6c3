"""The bay oracle: a reference that knows the true poses, for the hallway's time to localize.

Not a baseline (it reads the truth, which no policy may): it bounds what choosing the
way round the ring can buy. Each robot first turns in place until it faces the
shorter way round the ring to the bay (from its TRUE pose), then drives as
``corridor`` (which keeps circling, so it passes the bay). Everything else -- the
estimator, detections, the time-to-localize measure -- is the scenario's. It runs
next to the policies given, on the same seeds, and prints the comparison table and
the paired differences, like ``scripts/evaluate.py --compare``::

    python scripts/bench/bay_oracle.py --episodes 100 --seed 200000 --compare corridor
    python scripts/bench/bay_oracle.py --bay 10,4.5 --set obstacles=... (another map)

``--bay X,Y`` is the bay's centre in the map (default: the open area of
``symmetric_hallway``); the ring's centre is the world's.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from coop_loc_env.cli import ScriptParser, run_script
from coop_loc_env.scenarios.fox import BAY, CORRIDOR, HALLWAY_SIZE
from policies.experiments.compare import (
    compare,
    format_compare_table,
    format_paired,
    parse_policy_list,
)
from policies.experiments.report import write_json
from policies.experiments.runner import parse_overrides
from policies.scripted.corridor import CorridorPolicy, follow
from policies.scripted.registry import register_policy

DEFAULT_BAY = (CORRIDOR + BAY[0] / 2, HALLWAY_SIZE / 2)
ORACLE = "bay_oracle"


class BayOraclePolicy(CorridorPolicy):
    """Turn (true pose) to the shorter way round to ``bay``, then drive as ``corridor``."""

    name = ORACLE

    def __init__(self, bay: tuple[float, float] = DEFAULT_BAY) -> None:
        super().__init__(1.0)
        self.bay = np.asarray(bay, dtype=float)

    def reset(self, env, seed: int | None = None) -> None:
        super().reset(env, seed)
        centre = np.asarray(env.config.world_size, dtype=float) / 2
        poses = env.world.poses
        bay_angle = math.atan2(*(self.bay - centre)[::-1])
        self.turning = {}
        for i, (x, y, th) in enumerate(poses):
            ccw_gap = (bay_angle - math.atan2(y - centre[1], x - centre[0])) % (2 * math.pi)
            want_ccw = ccw_gap < math.pi
            going_ccw = (x - centre[0]) * math.sin(th) - (y - centre[1]) * math.cos(th) > 0
            self.turning[i] = 0.0 if want_ccw == going_ccw else math.pi  # radians left to turn
        self.turn_step = env.config.dt * env.config.max_turn_rate

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {}
        for agent in self.env.agents:
            i = self.env.agent_name_mapping[agent]
            if self.turning[i] > 0:
                self.turning[i] -= self.turn_step
                out[agent] = np.array([0.0, 1.0], dtype=np.float32)
            else:
                out[agent] = follow(self._view(i), self.speed, self.gain)
        return out


def main(argv: list[str] | None = None) -> int:
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="active_hallway")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--seed", type=int, default=200_000)
    p.add_argument("--compare", default="corridor", metavar="A,B,...",
                   help="policies run beside the oracle on the same seeds")
    p.add_argument("--bay", default=None, metavar="X,Y", help="the bay's centre (m)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    try:
        bay = DEFAULT_BAY if args.bay is None else tuple(float(v) for v in args.bay.split(","))
        if len(bay) != 2:
            raise ValueError(f"--bay must be X,Y, got {args.bay!r}")
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        register_policy(ORACLE, lambda _arg: BayOraclePolicy(bay),
                        "drives the shorter way to the bay knowing the true poses (reference)")
        specs = [ORACLE, *parse_policy_list(args.compare)]
        data = compare(args.scenario, specs, args.episodes, args.seed,
                       parse_overrides(args.overrides), progress=False)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(format_compare_table(data, ("time_to_localize_s", "localized_fraction",
                                      "localized_at_end", "collisions")))
    print(format_paired(data, ORACLE))
    if args.json is not None:
        write_json(data, args.json)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
