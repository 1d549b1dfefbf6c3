"""Stress the landmark lock-out recovery of the team EKF on MR.CLAM logs. Prints figures.

Replays one MR.CLAM dataset (the README's protocol, the shipped noise
parameters) over time windows, clean and with synthetic corruptions of its
readings, through ``ekf`` (landmarks only) and ``ekf_team``:

* ``clean``: the logs as they are.
* ``biased_landmark``: the map puts landmark ``L`` ``0.4 m`` from where it is
  (readings of it are consistently wrong for every robot).
* ``misidentified``: every reading of landmark ``L`` is labelled as landmark
  ``M`` (a barcode read wrong), so the filter places it at ``M``.
* ``turn_bursts``: readings taken while a robot turns carry a bearing error of
  ``0.25 s`` times the turn rate (a time stamp late by a quarter second): bursts
  of rejections that agree with each other while the robot turns.
* ``kidnapped``: robot 1 starts ``(3, -2) m`` from its true pose with the usual
  small covariance (only in the first window): seconds from its first landmark
  reading until it is within 0.5 m.

Per case: mean position error, NEES95 (share of times inside the 95 % ellipse),
rejected readings, recoveries (where the code reports them), and per robot the
mean error and the RMSE. The script only uses the replay's public functions,
so the same file can score another tree of the code (put it first on
``PYTHONPATH``).

    python scripts/bench/recovery_stress.py /work/shared/data/mrclam/MRCLAM_Dataset6 \
        --windows 0:300 300:300 --landmarks 8 16 --json out.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys

import numpy as np

import estimators.replay.runner as runner
from estimators.mrclam import MrclamDataset, load_mrclam
from estimators.replay import evaluate, load_noise_parameters

KIDNAP_OFFSET = (3.0, -2.0)
BIAS_M = 0.4
LATE_S = 0.25
# A landmark of another group (MR.CLAM's landmarks stand in clusters a few decimetres wide).
MISLABEL = {6: 16, 7: 17, 8: 18, 9: 19, 10: 20, 11: 14, 12: 15, 13: 16, 14: 6, 15: 7, 16: 8,
            17: 9, 18: 10, 19: 11, 20: 12}


def biased_landmark(data: MrclamDataset, lm: int) -> MrclamDataset:
    """The map has landmark ``lm`` :data:`BIAS_M` off (along the diagonal)."""
    marks = dict(data.landmarks)
    marks[lm] = marks[lm] + BIAS_M / np.sqrt(2.0)
    return dataclasses.replace(data, landmarks=marks)


def misidentified(data: MrclamDataset, lm: int) -> MrclamDataset:
    """Every reading of ``lm`` is labelled as :data:`MISLABEL` ``[lm]``."""
    robots = {}
    for rid, log in data.robots.items():
        m = log.measurements.copy()
        m[m[:, 1] == lm, 1] = MISLABEL[lm]
        robots[rid] = dataclasses.replace(log, measurements=m)
    return dataclasses.replace(data, robots=robots)


def turn_bursts(data: MrclamDataset, late_s: float = LATE_S) -> MrclamDataset:
    """Bearing error ``late_s * w`` on every reading (``w``: the commanded turn rate then)."""
    robots = {}
    for rid, log in data.robots.items():
        m = log.measurements.copy()
        odo = log.odometry
        k = np.clip(np.searchsorted(odo[:, 0], m[:, 0], side="right") - 1, 0, len(odo) - 1)
        m[:, 3] += late_s * odo[k, 2]
        robots[rid] = dataclasses.replace(log, measurements=m)
    return dataclasses.replace(data, robots=robots)


def run_case(data, estimator: str, params, start: float, duration: float, kidnap: bool) -> dict:
    """Replay one case; its figures (see the module doc)."""
    original = runner.TeamEKF
    if kidnap:
        class Kidnapped(original):
            def __init__(self, tracks, mean, cov, t0, *args, **kw):
                mean = np.array(mean, dtype=float)
                mean[0, :2] += KIDNAP_OFFSET
                super().__init__(tracks, mean, cov, t0, *args, **kw)
        runner.TeamEKF = Kidnapped
    made = []
    cls = runner.TeamEKF

    class Watched(cls):
        def __init__(self, *args, **kw):
            super().__init__(*args, **kw)
            made.append(self)

    runner.TeamEKF = Watched
    try:
        res = runner.replay(data, estimator, params, duration=duration, start_offset=start)
    finally:
        runner.TeamEKF = original
    m = evaluate(res)
    ekf = made[-1]
    out = {
        "mean_position_error_m": round(m["mean_position_error_m"], 4),
        "nees_95_fraction": round(m["nees_95_fraction"], 3),
        "rejected": m["rejected_measurements"],
        "recoveries": _recoveries(ekf),
        "per_robot": {
            r["robot"]: [round(r["mean_position_error_m"], 3), round(r["position_rmse_m"], 3),
                         r["rejected_measurements"]]
            for r in m["per_robot"]
        },
    }
    if kidnap:
        d = res.estimate[0, :, :2] - res.truth[0, :, :2]
        err = np.where(res.valid[0], np.hypot(d[:, 0], d[:, 1]), np.nan)
        stream = data.robots[data.robot_ids[0]].measurements
        t_start = res.times[0] - 1.0
        seen = stream[np.isin(stream[:, 1], list(data.landmarks)) & (stream[:, 0] > t_start), 0]
        first = float(seen[0]) if len(seen) else np.nan
        close = np.nonzero((err < 0.5) & (res.times >= first))[0]
        out["robot1_first_landmark_s"] = round(first - t_start, 1)
        out["robot1_seconds_to_0.5m_after_first_landmark"] = (
            round(float(res.times[close[0]] - first), 1) if len(close) else None
        )
    return out


def _recoveries(ekf) -> int | None:
    for name in ("relocalizer", "monitor"):
        obj = getattr(ekf, name, None)
        if obj is not None and hasattr(obj, "recoveries"):
            return int(obj.recoveries)
    return None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset_dir")
    p.add_argument("--windows", nargs="+", default=["0:300", "300:300"],
                   help="START:DURATION in seconds after the latest odometry start")
    p.add_argument("--landmarks", nargs="+", type=int, default=[8, 16],
                   help="landmarks to corrupt, one case each")
    p.add_argument("--cases", nargs="+",
                   default=["clean", "biased_landmark", "misidentified", "turn_bursts",
                            "kidnapped"])
    p.add_argument("--estimators", nargs="+", default=["ekf", "ekf_team"])
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    try:
        windows = [tuple(float(x) for x in w.split(":")) for w in args.windows]
        if any(len(w) != 2 for w in windows):
            raise ValueError
    except ValueError:
        print(f"--windows takes START:DURATION pairs, got {args.windows!r}", file=sys.stderr)
        return 2
    data = load_mrclam(args.dataset_dir)
    bad = [lm for lm in args.landmarks if lm not in data.landmarks]
    if bad:
        print(f"--landmarks: no such landmark {bad[0]!r}", file=sys.stderr)
        return 2
    params = load_noise_parameters()
    variants = []
    for case in args.cases:
        if case in ("biased_landmark", "misidentified"):
            fn = biased_landmark if case == "biased_landmark" else misidentified
            variants += [(f"{case} {lm}", fn(data, lm), False) for lm in args.landmarks]
        elif case == "turn_bursts":
            variants.append((case, turn_bursts(data), False))
        elif case == "kidnapped":
            variants.append((case, data, True))
        elif case == "clean":
            variants.append((case, data, False))
        else:
            print(f"unknown case {case!r}", file=sys.stderr)
            return 2
    out = {}
    for start, duration in windows:
        for name, d, kidnap in variants:
            if kidnap and start > 0:
                continue
            for est in args.estimators:
                key = f"{start:g}:{duration:g} {name} {est}"
                out[key] = run_case(d, est, params, start, duration, kidnap)
                print(key, json.dumps(out[key]), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
