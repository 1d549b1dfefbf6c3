"""Cost per step of scripted policies: milliseconds per team step spent in ``act`` vs the env.

Example::

    python scripts/bench/policy_step.py --scenario rendezvous --policies gather,infogain,fsm \\
        --episodes 2

Prints, per policy, the mean time of ``policy.act`` and of ``env.step`` per team
step (one call each for the whole team) over the episodes, and their ratio.
"""

from __future__ import annotations

import sys
import time

import coop_loc_env
from coop_loc_env.cli import ScriptParser, run_script
from policies.episode import env_overrides_for
from policies.experiments.compare import parse_policy_list, resolve_policy
from policies.experiments.runner import parse_overrides


def bench(scenario: str, spec: str, episodes: int, overrides: dict) -> tuple[float, float]:
    """``(ms per act call, ms per env step)`` of ``spec`` over ``episodes`` seeded episodes."""
    policy = resolve_policy(spec)
    env = coop_loc_env.parallel_env(scenario, **env_overrides_for(policy, overrides))
    t_act = t_env = 0.0
    steps = 0
    for k in range(episodes):
        obs, _ = env.reset(seed=k)
        policy.reset(env, seed=k)
        while env.agents:
            t0 = time.perf_counter()
            actions = policy.act(obs)
            t1 = time.perf_counter()
            obs, *_ = env.step(actions)
            t_env += time.perf_counter() - t1
            t_act += t1 - t0
            steps += 1
    env.close()
    return 1e3 * t_act / steps, 1e3 * t_env / steps


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="rendezvous")
    p.add_argument("--policies", default="gather,infogain,fsm")
    p.add_argument("--episodes", type=int, default=2)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = p.parse_args(argv)
    try:
        specs = parse_policy_list(args.policies)
        overrides = parse_overrides(args.overrides)
        if args.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
        print(f"{'policy':<10} {'act ms/step':>12} {'env ms/step':>12} {'act/env':>8}")
        for spec in specs:
            act, env = bench(args.scenario, spec, args.episodes, overrides)
            print(f"{spec:<10} {act:>12.3f} {env:>12.3f} {act / env:>8.2f}")
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
