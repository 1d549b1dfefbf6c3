"""BenchMARL training time of one short run per torch thread setting, alternated.

Runs ``python -m benchmarl.run algorithm=ALGO task=coop_loc/SCENARIO
experiment=coop_loc_short`` once per setting per round (settings alternate within each
round, so that the machine's load hits them alike; ``--override`` adds hydra overrides),
with ``COOP_LOC_TORCH_THREADS`` set to
each of ``--threads`` (0: torch's default, one thread per core), and prints the run's
own total time (BenchMARL's ``timers/total_time``: collection, training and evaluation,
without the imports), median over the rounds, and its ratio to the best setting::

    python scripts/bench/torch_threads.py --rounds 2 --threads 0,1,2
"""

from __future__ import annotations

import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from coop_loc_env.cli import ScriptParser, run_script

ROOT = Path(__file__).resolve().parents[2]


def one_run(algo: str, scenario: str, threads: int, workdir: Path,
            overrides: list[str] | tuple = ()) -> float:
    """The BenchMARL total time (s) of one short run with ``threads``."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    env["COOP_LOC_TORCH_THREADS"] = str(threads)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    out = workdir / f"t{threads}_{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "benchmarl.run", f"algorithm={algo}",
           f"task=coop_loc/{scenario}", "experiment=coop_loc_short",
           f"hydra.run.dir={out}", f"experiment.save_folder={out}", *overrides]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"error: {' '.join(cmd)} failed: {done.stderr.strip()[-300:]}")
    timer = next(out.rglob("timers_total_time.csv"))
    with timer.open() as f:
        return float(list(csv.reader(f))[-1][1])


def main(argv: list[str] | None = None) -> int:
    """Run the rounds and print the table; returns the exit status."""
    p = ScriptParser(description=__doc__.splitlines()[0])
    p.add_argument("--algo", default="mappo")
    p.add_argument("--scenario", default="rendezvous")
    p.add_argument("--threads", default="0,1,2", help="settings, 0 = torch's default")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--override", action="append", default=[], metavar="KEY=VALUE",
                   help="hydra override on top of the preset, repeatable (e.g. "
                        "experiment.max_n_frames=2000)")
    args = p.parse_args(argv)
    settings = [int(t) for t in args.threads.split(",")]
    times: dict[int, list[float]] = {t: [] for t in settings}
    print(f"{os.cpu_count()} CPUs; load average at the start {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            order = settings if r % 2 == 0 else settings[::-1]
            for t in order:
                times[t].append(one_run(args.algo, args.scenario, t, Path(tmp), args.override))
                print(f"round {r + 1}, threads {t}: {times[t][-1]:.1f} s", flush=True)
    print(f"{os.cpu_count()} CPUs; load average at the end {os.getloadavg()[0]:.1f}")
    medians = {t: statistics.median(v) for t, v in times.items()}
    best = min(medians.values())
    print(f"{'torch threads':<24} {'total time (s), median':>24} {'runs':>18} {'vs best':>8}")
    for t in settings:
        label = f"{t} (torch's default)" if t == 0 else str(t)
        runs = ", ".join(f"{x:.1f}" for x in times[t])
        print(f"{label:<24} {medians[t]:>24.1f} {runs:>18} {medians[t] / best:>7.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
