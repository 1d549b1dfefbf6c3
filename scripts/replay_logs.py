"""Replay real multi-robot logs (UTIAS MR.CLAM format) through the estimators.

Examples::

    python scripts/replay_logs.py ../shared/data/mrclam/MRCLAM_Dataset6 --estimator ekf_team \\
        --duration 600 --json out.json --plot out.png
    python scripts/replay_logs.py DATASET --estimator ekf_team --no-landmarks
    # estimate noise parameters from ground truth over a time span, write them, then reuse:
    python scripts/replay_logs.py DATASET --fit --fit-start 600 --fit-end 900 --params my.json
    python scripts/replay_logs.py OTHER_DATASET --estimator ekf --params my.json

Protocol: start at the latest odometry start of the robots (plus
``--start-offset``), initialize each robot at its ground-truth pose there,
run through the logs, and evaluate on a 1 s grid against interpolated ground
truth. ``--fit`` times are seconds after that latest odometry start. Without
``--params`` the parameters shipped in ``estimators/data/mrclam_noise.json``
are used (fitted on MR.CLAM dataset 6 outside the default 600 s window).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

# The matrices here are tiny (<= ~200 x 200): BLAS worker threads only add overhead and,
# on a shared machine, can slow the pose-graph solver down several times. Set before numpy.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from coop_loc_env.cli import ScriptParser, require, run_script  # noqa: E402
from estimators.log_replay import (  # noqa: E402
    DEFAULT_NOISE_PATH,
    ESTIMATORS,
    evaluate,
    fit_noise_parameters,
    load_noise_parameters,
    replay,
    save_noise_parameters,
)
from estimators.mrclam import load_mrclam  # noqa: E402


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line arguments."""
    p = ScriptParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("dataset_dir", type=Path, help="MR.CLAM dataset directory")
    p.add_argument("--estimator", choices=ESTIMATORS, default="ekf_team")
    p.add_argument(
        "--no-landmarks", action="store_true", help="use robot-to-robot measurements only"
    )
    p.add_argument(
        "--no-landmark-screen",
        action="store_true",
        help="do not count the offset of a landmark several robots find off as map uncertainty",
    )
    p.add_argument("--duration", type=float, default=600.0, help="seconds to replay [600]")
    p.add_argument(
        "--start-offset", type=float, default=0.0, help="seconds after the latest odometry start"
    )
    p.add_argument("--json", type=Path, help="write the metrics as JSON here")
    p.add_argument("--plot", type=Path, help="write a trajectory/error figure here")
    p.add_argument(
        "--params",
        type=Path,
        help=f"noise parameter file to read (or, with --fit, to write) [{DEFAULT_NOISE_PATH.name}]",
    )
    p.add_argument(
        "--fit",
        action="store_true",
        help="estimate noise parameters from ground truth and write them to --params",
    )
    p.add_argument("--fit-start", type=float, default=0.0, help="fit span start [s after start]")
    p.add_argument("--fit-end", type=float, default=None, help="fit span end [default: log end]")
    p.add_argument("--fit-global-only", action="store_true", help="fit no per-robot calibration")
    p.add_argument(
        "--no-tune",
        action="store_true",
        help="with --fit: skip the consistency tuning replays (raw white-noise statistics)",
    )
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return p.parse_args(argv)


def _plot(result, metrics: dict, path: Path, landmarks: dict | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(13, 5.5))
    for i, rid in enumerate(result.robot_ids):
        ok = result.valid[i]
        (line,) = ax0.plot(result.truth[i, ok, 0], result.truth[i, ok, 1], lw=1.0, alpha=0.5)
        ax0.plot(
            result.estimate[i, :, 0],
            result.estimate[i, :, 1],
            "--",
            lw=1.0,
            color=line.get_color(),
            label=f"robot {rid}",
        )
        err = np.full(len(result.times), np.nan)
        d = result.estimate[i, ok, :2] - result.truth[i, ok, :2]
        err[ok] = np.hypot(d[:, 0], d[:, 1])
        ax1.plot(result.times - result.times[0], err, lw=0.8, label=f"robot {rid}")
    if landmarks:
        xy = np.array(list(landmarks.values()))
        ax0.plot(xy[:, 0], xy[:, 1], "k^", ms=5, label="landmarks")
    ax0.set_aspect("equal")
    ax0.set_xlabel("x [m]")
    ax0.set_ylabel("y [m]")
    ax0.set_title("truth (solid) and estimate (dashed)")
    ax0.legend(fontsize=8)
    ax1.set_xlabel("time [s]")
    ax1.set_ylabel("position error [m]")
    ax1.set_yscale("log")
    ax1.set_title(
        f"{metrics['estimator']}{'' if metrics['use_landmarks'] else ' (no landmarks)'}: "
        f"mean {metrics['mean_position_error_m']:.3f} m, "
        f"95% coverage {metrics['nees_95_fraction']:.2f}"
    )
    ax1.legend(fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit status (2, with one line on stderr, on bad input:
    a missing folder or file, a malformed line, a bad parameter file)."""
    args = parse_args(argv)
    if args.plot:
        require("matplotlib")  # the figure comes after the replay: fail before it
    if not args.no_progress:
        require("tqdm")
    try:
        return _run(args)
    except (OSError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    dataset = load_mrclam(args.dataset_dir)
    if dataset.unknown_barcodes:
        print(f"skipped unknown barcodes (barcode: count): {dataset.unknown_barcodes}")
    if args.fit:
        if args.params is None:
            print("--fit needs --params PATH to write the fitted parameters to", file=sys.stderr)
            return 2
        t0 = dataset.latest_odometry_start()
        end = None if args.fit_end is None else t0 + args.fit_end
        wall = time.perf_counter()
        params = fit_noise_parameters(
            dataset,
            t0 + args.fit_start,
            end,
            per_robot=not args.fit_global_only,
            tune=not args.no_tune,
        )
        save_noise_parameters(params, args.params)
        print(f"fitted in {time.perf_counter() - wall:.1f} s: {params.fitted_on}")
        print(f"wrote {args.params}")
        return 0
    params = load_noise_parameters(args.params)
    available = dataset.end_time() - dataset.latest_odometry_start() - args.start_offset
    if args.duration > available > 0:
        print(
            f"note: {args.dataset_dir} holds {available:.0f} s of odometry from the start; "
            f"replaying {available:.0f} s, not the {args.duration:g} s of --duration"
        )
        args.duration = available
    bar = None
    progress = None
    if not args.no_progress:
        from tqdm import tqdm

        bar = tqdm(total=100, desc=args.estimator, unit="%", leave=False)

        def progress(frac: float) -> None:
            bar.n = int(round(100 * frac))
            bar.refresh()

    result = replay(
        dataset,
        args.estimator,
        params,
        duration=args.duration,
        use_landmarks=not args.no_landmarks,
        start_offset=args.start_offset,
        progress=progress,
        screen_landmarks=not args.no_landmark_screen,
    )
    if bar is not None:
        bar.close()
    metrics = evaluate(result)
    metrics["dataset"] = str(args.dataset_dir)
    metrics["params"] = str(args.params or DEFAULT_NOISE_PATH)
    metrics["start_offset_s"] = args.start_offset
    metrics["skipped_unknown_barcodes"] = {str(k): v for k, v in dataset.unknown_barcodes.items()}
    print(
        f"{'robot':>5} {'mean[m]':>8} {'rmse[m]':>8} {'head[deg]':>9} {'final[m]':>8} "
        f"{'in95%':>6} {'rejected':>8}"
    )
    for r in metrics["per_robot"]:
        print(
            f"{r['robot']:>5} {r['mean_position_error_m']:8.3f} {r['position_rmse_m']:8.3f} "
            f"{r['mean_heading_error_deg']:9.2f} {r['final_position_error_m']:8.3f} "
            f"{r['nees_95_fraction']:6.2f} {r['rejected_measurements']:8d}"
        )
    print(
        f"{'mean':>5} {metrics['mean_position_error_m']:8.3f} {metrics['position_rmse_m']:8.3f} "
        f"{metrics['mean_heading_error_deg']:9.2f} {metrics['final_position_error_m']:8.3f} "
        f"{metrics['nees_95_fraction']:6.2f} {metrics['rejected_measurements']:8d}"
    )
    print(f"run time {metrics['runtime_s']:.2f} s")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(metrics, indent=2) + "\n")
    if args.plot:
        _plot(result, metrics, args.plot, dataset.landmarks)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
