"""Cost of the dict observation (belief modes and belief map) against the env step. Prints figures.

Runs ``--episodes`` seeded episodes of the scenario (``corridor`` driving) twice
over, alternating a flat-observation env and a dict one (``obs_format="dict"``)
episode by episode on the same seeds, and reports per team step:

* ``flat step`` and ``dict step``: the mean wall time of ``env.step`` (ms);
* ``blocks``: the time of building the dict observation's extra blocks alone
  (``TeamBeliefs.from_env`` + ``DictObservation.observe_all``), timed again right
  after each dict step on the same beliefs, and its share of the flat step.

    python scripts/bench/belief_map.py [--scenario active_hallway] [--episodes 6]
"""

from __future__ import annotations

import sys
import time

import numpy as np

import coop_loc_env
from coop_loc_env.belief_map import TeamBeliefs
from coop_loc_env.cli import ScriptParser, run_script
from policies.learning.loader import make_policy


def _episode(env, seed: int, blocks: list[float] | None) -> list[float]:
    """Step times (s) of one ``corridor`` episode; the blocks' times appended to ``blocks``."""
    policy = make_policy("corridor")
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed=seed)
    times = []
    while env.agents:
        actions = policy.act(obs)
        t = time.perf_counter()
        obs, *_ = env.step(actions)
        times.append(time.perf_counter() - t)
        if blocks is not None:  # the belief's modes and map, built again and timed
            named = {b.name: b for b in env.observations.blocks}
            modes, belief_map = named["belief_modes"], named["belief_map"]
            t = time.perf_counter()
            beliefs = TeamBeliefs.from_env(env)
            modes.values(beliefs)
            belief_map.values(beliefs)
            blocks.append(time.perf_counter() - t)
    return times


def main(argv: list[str] | None = None) -> int:
    p = ScriptParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="active_hallway")
    p.add_argument("--episodes", type=int, default=6)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.episodes < 1:
        print(f"error: --episodes must be >= 1, got {args.episodes}", file=sys.stderr)
        return 2
    try:
        flat_env = coop_loc_env.parallel_env(args.scenario)
        dict_env = coop_loc_env.parallel_env(args.scenario, obs_format="dict")
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    _episode(flat_env, args.seed, None)  # warm-up: compiled kernels, tables
    _episode(dict_env, args.seed, [])
    flat, dict_, blocks = [], [], []
    for k in range(args.episodes):
        flat += _episode(flat_env, args.seed + k, None)
        dict_ += _episode(dict_env, args.seed + k, blocks)
    f, d, b = (1e3 * float(np.mean(x)) for x in (flat, dict_, blocks))
    print(f"{args.scenario}: {args.episodes} episodes x2, {len(flat)} steps each format")
    print(f"flat step   {f:.3f} ms")
    print(f"dict step   {d:.3f} ms  ({100 * (d - f) / f:+.1f} % vs flat)")
    print(f"blocks      {b:.3f} ms  ({100 * b / f:.1f} % of the flat step)")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
