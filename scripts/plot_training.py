"""Plot a training run's learning curves: training return and the periodic evaluations.

Example::

    python scripts/plot_training.py --run runs/rendezvous --out docs/figures/rendezvous_training.png

Left: ``rollout/ep_rew_mean`` (mean return per robot-episode) from the run's
TensorBoard log; right: the periodic evaluation's team localization error
(``DIR/train_summary.json``) next to the baseline's on the same seeds.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from coop_loc_env.cli import ScriptParser, require, run_script


def tb_scalars(tb_dir: Path, tag: str) -> tuple[list[int], list[float]]:
    """Steps and values of scalar ``tag`` in every event file under ``tb_dir``."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    steps: list[int] = []
    values: list[float] = []
    for events in sorted(tb_dir.rglob("events.out.tfevents.*")):
        acc = EventAccumulator(str(events))
        acc.Reload()
        if tag in acc.Tags().get("scalars", []):
            for e in acc.Scalars(tag):
                steps.append(e.step)
                values.append(e.value)
    return steps, values


def main(argv: list[str] | None = None) -> int:
    """Write the figure; returns the exit status."""
    p = ScriptParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", type=Path, required=True, help="training output directory")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = p.parse_args(argv)
    require("matplotlib")
    summary_path = args.run / "train_summary.json"
    if not summary_path.is_file():
        print(f"error: no train_summary.json in {str(args.run)!r}", file=sys.stderr)
        return 2
    summary = json.loads(summary_path.read_text())
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.4))
    steps, values = tb_scalars(args.run / "tb", "rollout/ep_rew_mean")
    a.plot(steps, values, lw=1.2)
    a.set(xlabel="agent steps (PPO)", ylabel="return per robot-episode",
          title="training return")
    evals = summary.get("evals", [])
    if evals:
        b.plot([e["timesteps"] for e in evals], [e["localization_error_m"] for e in evals],
               "o-", label="learned (step 0: the clone)")
    if summary.get("baseline"):
        config_path = args.run / "train_config.json"
        config = json.loads(config_path.read_text()) if config_path.is_file() else {}
        b.axhline(summary["baseline"]["localization_error_m"], color="gray", ls="--",
                  label=f"{config.get('eval_baseline', 'fsm')}, same seeds")
    b.set(xlabel="agent steps (PPO)", ylabel="team loc. error (m)",
          title="evaluation (training layout)")
    b.legend(fontsize=8)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
