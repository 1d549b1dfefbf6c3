"""Step time of the env bare, through the native TorchRL env and through PettingZooWrapper.

Random actions, episodes reset when done; all are timed in alternation, ``--reps``
rounds of ``--steps`` steps each, and the ratios are of the per-round medians.
``torchrl_env`` and ``PettingZooWrapper`` are timed through ``rollout``; the
``torchrl_env._step`` and ``torchrl_env.step`` rows call those methods in a loop (what
the env and this package's tensor work cost, then with TorchRL's own step logic)::

    python scripts/bench/torchrl_step.py --scenario rendezvous --steps 400 --reps 5
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from coop_loc_env.cli import ScriptParser, require, run_script


def _bare(env, steps: int, rng: np.random.Generator) -> float:
    t0 = time.perf_counter()
    done = 0
    while done < steps:
        if not env.agents:
            env.reset()
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        done += 1
    return (time.perf_counter() - t0) / steps


def _native_calls(env, steps: int, method: str) -> float:
    """``env._step`` (the env and this package's tensor work) or ``env.step`` (plus
    TorchRL's checks and done bookkeeping), one fixed random action, resets outside."""
    import torch

    td = env.reset()
    td.set(("robot", "action"), torch.rand(env.n_agents, 2) * 2 - 1)
    call = getattr(env, method)
    t0 = time.perf_counter()
    for _ in range(steps):
        if not env.env.agents:
            env.reset()
        call(td.clone(False))
    return (time.perf_counter() - t0) / steps


def _torchrl(env, steps: int) -> float:
    t0 = time.perf_counter()
    env.rollout(steps, break_when_any_done=False)
    return (time.perf_counter() - t0) / steps


def main(argv: list[str] | None = None) -> int:
    p = ScriptParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="rendezvous")
    p.add_argument("--steps", type=int, default=400)
    p.add_argument("--reps", type=int, default=5)
    args = p.parse_args(argv)
    require("torch", "tensordict", "torchrl", extra="torchrl")
    if args.steps < 1 or args.reps < 1:
        print(f"error: --steps and --reps must be >= 1, got {args.steps}, {args.reps}",
              file=sys.stderr)
        return 2
    import torch
    from torchrl.envs.libs.pettingzoo import PettingZooWrapper

    import coop_loc_env

    torch.set_num_threads(1)
    bare = coop_loc_env.parallel_env(args.scenario)
    bare.reset(seed=0)
    native = coop_loc_env.torchrl_env(args.scenario, seed=0)
    wrapped = PettingZooWrapper(env=coop_loc_env.parallel_env(args.scenario), use_mask=True,
                                done_on_any=False, seed=0)
    rng = np.random.default_rng(0)
    times: dict[str, list[float]] = {"bare": [], "torchrl_env": [], "PettingZooWrapper": [],
                                     "torchrl_env._step": [], "torchrl_env.step": []}
    _torchrl(native, 20), _torchrl(wrapped, 20), _bare(bare, 20, rng)  # warm up
    for _ in range(args.reps):
        times["bare"].append(_bare(bare, args.steps, rng))
        times["torchrl_env"].append(_torchrl(native, args.steps))
        times["PettingZooWrapper"].append(_torchrl(wrapped, args.steps))
        times["torchrl_env._step"].append(_native_calls(native, args.steps, "_step"))
        times["torchrl_env.step"].append(_native_calls(native, args.steps, "step"))
    base = statistics.median(times["bare"])
    print(f"{args.scenario}: {args.reps} alternating rounds of {args.steps} random-action steps")
    for name, ts in times.items():
        med = statistics.median(ts)
        ratios = [t / b for t, b in zip(ts, times["bare"], strict=True)]
        print(f"{name:18s} {1e3 * med:6.3f} ms/step  {1 / med:7.0f} steps/s  "
              f"x{med / base:.2f} bare (rounds x{min(ratios):.2f}-x{max(ratios):.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_script(main))
