"""Env steps per second of the batched env (``vector_env``) next to our single env and VMAS.

EKF ``rendezvous`` (4 robots, random actions in ``[-1, 1]``, worlds reset as they end)
through ``coop_loc_env.vector_env(num_envs=B)`` for each ``--sizes`` B, our single
``parallel_env`` (its PettingZoo dicts), and VMAS ``navigation`` (4 agents with lidar,
CPU, ``--torch-threads`` torch threads) at each B when ``vmas`` is installed (the
``bench`` extra), and with ``--torchrl`` the batched TorchRL env
(``torchrl_env(num_envs=B)``, ``step_and_maybe_reset``). The sides alternate in
``--rounds`` rounds of ``--seconds`` wall-clock seconds each; the figures are the
medians of the rounds, the ratios of the per-round figures. Env steps count worlds:
one batched step of B worlds is B env steps::

    python scripts/bench/vector_env.py [--sizes 1 64 1024] [--seconds 2] [--rounds 3] [--torchrl]

``--trainers N`` instead times the trainers' sampling over N worlds: SB3's env copies
against the batched ``VecEnv`` (agent steps/s), TorchRL's ``SerialEnv`` of N single envs
against ``torchrl_env(num_envs=N)`` (env steps/s).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

import coop_loc_env

SCENARIO, N_ROBOTS = "rendezvous", 4
#: The env settings the sides are built with (``--scenario``, ``--obs-format``).
SETTINGS: dict = {"scenario": SCENARIO, "estimator": "ekf"}


def _ours(num_envs: int) -> Callable[[], int]:
    """One batched step of ``num_envs`` worlds per call; returns the env steps taken."""
    env = coop_loc_env.vector_env(num_envs=num_envs, **SETTINGS)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, (num_envs, env.n_robots, 2)) for _ in range(8)]
    count = [0]

    def step() -> int:
        env.step(actions[count[0] % 8])
        count[0] += 1
        return num_envs

    return step


def _single() -> Callable[[], int]:
    env = coop_loc_env.parallel_env(**SETTINGS)
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step() -> int:
        if not env.agents:
            env.reset()
        env.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents})
        return 1

    return step


def _vmas(num_envs: int, threads: int) -> Callable[[], int] | None:
    try:
        import torch
        import vmas
    except ImportError:
        return None
    torch.set_num_threads(threads)
    env = vmas.make_env("navigation", num_envs=num_envs, device="cpu",
                        continuous_actions=True, n_agents=N_ROBOTS, seed=0)
    env.reset()
    gen = torch.Generator().manual_seed(0)
    actions = [[torch.rand(num_envs, 2, generator=gen) * 2 - 1 for _ in range(N_ROBOTS)]
               for _ in range(8)]
    count = [0]

    def step() -> int:
        _, _, dones, _ = env.step(actions[count[0] % 8])
        count[0] += 1
        if bool(dones.any()):
            for i in torch.nonzero(dones).flatten().tolist():
                env.reset_at(i)
        return num_envs

    return step


def _torchrl(num_envs: int) -> Callable[[], int]:
    """``torchrl_env(num_envs=B).step`` with a fixed random action, done worlds reset."""
    import torch

    env = coop_loc_env.torchrl_env(num_envs=num_envs, seed=0, **SETTINGS)
    td = env.reset()
    td.set(("robot", "action"), torch.rand(num_envs, env.n_agents, 2) * 2 - 1)
    return _stepping(env, td, num_envs)


def _stepping(env, td, num_envs: int) -> Callable[[], int]:
    """A step of a TorchRL env from ``td`` (done worlds reset), the action held fixed;
    returns the env steps taken."""
    state = [td]

    def step() -> int:
        _, state[0] = env.step_and_maybe_reset(state[0])
        state[0].set(("robot", "action"), td.get(("robot", "action")))
        return num_envs

    return step


def _sb3(kind: str, n_envs: int) -> Callable[[], int]:
    """A step of the SB3 ``VecEnv`` of ``n_envs`` worlds (``copies`` or ``batched``);
    returns the agent steps taken."""
    from policies.learning.sb3_batched import BatchedVecEnv
    from policies.learning.sb3_vec_env import ParallelEnvVecEnv
    from policies.learning.vec_env import make_env_fn

    settings = {k: v for k, v in SETTINGS.items() if k != "scenario"}
    venv = (BatchedVecEnv(SETTINGS["scenario"], n_envs=n_envs, **settings) if kind == "batched"
            else ParallelEnvVecEnv(make_env_fn(SETTINGS["scenario"], **settings), n_envs=n_envs))
    venv.seed(0)
    venv.reset()
    act = np.random.default_rng(0).uniform(-1, 1, (venv.num_envs, 2)).astype(np.float32)

    def step() -> int:
        venv.step(act)
        return venv.num_envs

    return step


def _serial_torchrl(num_envs: int) -> Callable[[], int]:
    """TorchRL's ``SerialEnv`` of ``num_envs`` single TorchRL envs, one step of all."""
    import torch
    from torchrl.envs import SerialEnv

    env = SerialEnv(num_envs, lambda: coop_loc_env.torchrl_env(seed=0, **SETTINGS))
    td = env.reset()
    td.set(("robot", "action"), torch.rand(*td["robot", "observation"].shape[:2], 2) * 2 - 1)
    return _stepping(env, td, num_envs)


def trainer_figures(seconds: float, rounds: int, n_envs: int = 8) -> dict:
    """SB3 agent steps/s (env copies vs the batched VecEnv) and TorchRL env steps/s
    (``SerialEnv`` of single envs vs ``torchrl_env(num_envs)``), alternating."""
    sides = {"sb3_copies": _sb3("copies", n_envs), "sb3_batched": _sb3("batched", n_envs),
             "torchrl_serial": _serial_torchrl(n_envs), "torchrl_batched": _torchrl(n_envs)}
    per_round: dict[str, list[float]] = {name: [] for name in sides}
    for _ in range(rounds):
        for name, step in sides.items():
            per_round[name].append(_rate(step, seconds))
    out: dict = {name: statistics.median(v) for name, v in per_round.items()}
    for kind in ("sb3", "torchrl"):
        base = "copies" if kind == "sb3" else "serial"
        out[f"{kind}_batched_over_{base}"] = statistics.median(
            b / c for b, c in zip(per_round[f"{kind}_batched"], per_round[f"{kind}_{base}"],
                                  strict=True))
    return out


def _rate(step: Callable[[], int], seconds: float) -> float:
    """Env steps per wall-clock second over about ``seconds``."""
    steps = step()  # a warm-up step
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        steps += step()
    return steps / (time.perf_counter() - start)


def measure(sizes: list[int], seconds: float, rounds: int, threads: int = 2,
            torchrl: bool = False, vmas: bool = True) -> dict:
    """The figures: per side the median env steps/s and the per-round values."""
    sides: dict[str, Callable[[], int]] = {"single": _single()}
    for b in sizes:
        sides[f"ours_B{b}"] = _ours(b)
        if torchrl:
            sides[f"torchrl_B{b}"] = _torchrl(b)
        vm = _vmas(b, threads) if vmas else None
        if vm is not None:
            sides[f"vmas_B{b}"] = vm
    per_round: dict[str, list[float]] = {name: [] for name in sides}
    for _ in range(rounds):
        for name, step in sides.items():
            per_round[name].append(_rate(step, seconds))
    out: dict = {name: statistics.median(v) for name, v in per_round.items()}
    for b in sizes:
        ours = per_round[f"ours_B{b}"]
        out[f"ours_B{b}_over_single"] = statistics.median(
            o / s for o, s in zip(ours, per_round["single"], strict=True))
        if f"torchrl_B{b}" in per_round:  # step time of torchrl_env over the bare step
            out[f"torchrl_B{b}_step_ratio"] = statistics.median(
                o / t for o, t in zip(ours, per_round[f"torchrl_B{b}"], strict=True))
        if f"vmas_B{b}" in per_round:
            out[f"ours_B{b}_over_vmas"] = statistics.median(
                o / v for o, v in zip(ours, per_round[f"vmas_B{b}"], strict=True))
    out["vmas_installed"] = any(name.startswith("vmas") for name in sides)
    return out


def bench_vector_env() -> dict:
    """The benchmark's figures (``scripts/benchmark.py`` prints them)."""
    return measure([1, 64, 1024], seconds=1.0, rounds=3)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 64, 1024])
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--torch-threads", type=int, default=2)
    p.add_argument("--torchrl", action="store_true",
                   help="also time torchrl_env(num_envs=B).step against the bare step")
    p.add_argument("--trainers", type=int, default=0, metavar="N",
                   help="instead: SB3 and TorchRL sampling over N worlds, copies vs batched")
    p.add_argument("--scenario", default=SCENARIO, help="our scenario (VMAS is left out "
                   "for another than rendezvous)")
    p.add_argument("--estimator", default="ekf")
    p.add_argument("--obs-format", default=None, choices=("flat", "dict"))
    args = p.parse_args(argv)
    if any(b < 1 for b in args.sizes) or not args.seconds > 0 or args.rounds < 1 or (
            args.torch_threads < 1):
        print("error: --sizes, --seconds, --rounds and --torch-threads must be positive",
              file=sys.stderr)
        return 2
    try:
        coop_loc_env.make_config(args.scenario, estimator=args.estimator)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    SETTINGS.update(scenario=args.scenario, estimator=args.estimator)
    if args.obs_format is not None:
        SETTINGS["obs_format"] = args.obs_format
    if args.trainers:
        figures = trainer_figures(args.seconds, args.rounds, args.trainers)
        print(f"{args.scenario} {args.estimator}, {args.trainers} worlds, median of "
              f"{args.rounds} rounds")
        print(f"  SB3 agent steps/s: env copies {figures['sb3_copies']:.0f}, batched VecEnv "
              f"{figures['sb3_batched']:.0f} ({figures['sb3_batched_over_copies']:.2f}x)")
        print(f"  TorchRL env steps/s: SerialEnv {figures['torchrl_serial']:.0f}, "
              f"torchrl_env(num_envs) {figures['torchrl_batched']:.0f} "
              f"({figures['torchrl_batched_over_serial']:.2f}x)")
        return 0
    vmas = args.scenario == SCENARIO
    figures = measure(args.sizes, args.seconds, args.rounds, args.torch_threads,
                      args.torchrl, vmas)
    print(f"env steps/s, {args.scenario} {args.estimator} "
          f"{coop_loc_env.make_config(args.scenario).n_robots} robots"
          + (f" vs VMAS navigation ({args.torch_threads} torch threads)" if vmas else "")
          + f", median of {args.rounds} rounds")
    print(f"  {'single parallel_env':<24} {figures['single']:>10.0f}")
    for b in args.sizes:
        line = (f"  {'vector_env B=' + str(b):<24} {figures[f'ours_B{b}']:>10.0f}   "
                f"{figures[f'ours_B{b}_over_single']:.2f}x single")
        if f"vmas_B{b}" in figures:
            line += (f"   VMAS {figures[f'vmas_B{b}']:>9.0f}   "
                     f"{figures[f'ours_B{b}_over_vmas']:.3f}x VMAS")
        print(line)
        if f"torchrl_B{b}" in figures:
            print(f"  {'torchrl_env B=' + str(b):<24} {figures[f'torchrl_B{b}']:>10.0f}   "
                  f"step {figures[f'torchrl_B{b}_step_ratio']:.2f}x the bare batched step")
    if vmas and not figures["vmas_installed"]:
        print("  (vmas is not installed: pip install -e \".[bench]\")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
