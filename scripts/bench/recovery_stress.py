"""Stress the landmark lock-out recovery of the team EKF on MR.CLAM logs. Prints figures.

Replays one MR.CLAM dataset (the README's protocol, the shipped noise
parameters) over time windows, clean and with synthetic corruptions of its
readings, through ``ekf`` (landmarks only) and ``ekf_team``:

* ``clean``: the logs as they are.
* ``biased_landmark``: the map puts landmark ``L`` ``--bias-m`` (0.4 m) from
  where it is (its readings are consistently wrong for every robot).
* ``misidentified``: every reading of landmark ``L`` is labelled as another
  landmark (a barcode read wrong): one of another cluster (``--mislabel far``)
  or a neighbour in its own (``near``).
* ``turn_bursts``: every bearing carries the error of a time stamp ``--late-s``
  (0.25 s) late, i.e. that time the turn rate: bursts of rejections that agree
  with each other while a robot turns.
* ``kidnapped``: one robot (``--kidnap``, default 1) starts ``--kidnap-offset``
  (3, -2 m) from its true pose with the usual small covariance: seconds from
  its first landmark reading until it is within 0.5 m.

``--noise-scale F`` replays with every measurement std multiplied by ``F`` and the process
noise densities by ``F**2`` (F < 1: a model F times too confident, as on a dataset noisier
than the one the parameters were fitted on).

Per case: mean position error, NEES95 (share of times inside the 95 % ellipse),
rejected readings, recoveries (where the code reports them), and per robot the
mean error, the RMSE and the rejected readings. The script only uses the
replay's public functions, so the same file can score another tree of the code
(put it first on ``PYTHONPATH``).

    python scripts/bench/recovery_stress.py /work/shared/data/mrclam/MRCLAM_Dataset6 \
        --windows 0:300 300:300 --landmarks 8 16 --json out.json"""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np

import estimators.replay.runner as runner
from coop_loc_env.cli import ScriptParser, run_script
from estimators.mrclam import MrclamDataset, load_mrclam
from estimators.replay import evaluate, load_noise_parameters, scale_noise

KIDNAP_OFFSET = (3.0, -2.0)
BIAS_M = 0.4
LATE_S = 0.25
# MR.CLAM's landmarks stand in clusters a few decimetres wide. "far": a landmark of another
# cluster; "near": a neighbour in the same one.
MISLABEL = {
    "far": {6: 16, 7: 17, 8: 18, 9: 19, 10: 20, 11: 14, 12: 15, 13: 16, 14: 6, 15: 7, 16: 8,
            17: 9, 18: 10, 19: 11, 20: 12},
    "near": {6: 7, 7: 8, 8: 6, 9: 10, 10: 9, 11: 12, 12: 13, 13: 11, 14: 15, 15: 14, 16: 17,
             17: 18, 18: 16, 19: 20, 20: 19},
}


def biased_landmark(data: MrclamDataset, lm: int, bias_m: float = BIAS_M) -> MrclamDataset:
    """The map has landmark ``lm`` ``bias_m`` off (along the diagonal)."""
    marks = dict(data.landmarks)
    marks[lm] = marks[lm] + bias_m / np.sqrt(2.0)
    return dataclasses.replace(data, landmarks=marks)


def misidentified(data: MrclamDataset, lm: int, kind: str = "far") -> MrclamDataset:
    """Every reading of ``lm`` is labelled as :data:`MISLABEL` ``[kind][lm]``."""
    robots = {}
    for rid, log in data.robots.items():
        m = log.measurements.copy()
        m[m[:, 1] == lm, 1] = MISLABEL[kind][lm]
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


def run_case(
    data, estimator: str, params, start: float, duration: float, kidnap: int | None = None,
    offset: tuple[float, float] = KIDNAP_OFFSET,
) -> dict:
    """Replay one case (``kidnap``: the robot to start off its pose); its figures."""
    original = runner.TeamEKF
    lost = None if kidnap is None else data.robot_ids.index(kidnap)
    if lost is not None:
        class Kidnapped(original):
            def __init__(self, tracks, mean, cov, t0, *args, **kw):
                mean = np.array(mean, dtype=float)
                mean[lost, :2] += offset
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
    if lost is not None:
        d = res.estimate[lost, :, :2] - res.truth[lost, :, :2]
        err = np.where(res.valid[lost], np.hypot(d[:, 0], d[:, 1]), np.nan)
        stream = data.robots[kidnap].measurements
        t_start = res.times[0] - 1.0
        seen = stream[np.isin(stream[:, 1], list(data.landmarks)) & (stream[:, 0] > t_start), 0]
        first = float(seen[0]) if len(seen) else np.nan
        close = np.nonzero((err < 0.5) & (res.times >= first))[0]
        out["kidnapped_robot"] = kidnap
        out["first_landmark_s"] = round(first - t_start, 1)
        out["seconds_to_0.5m_after_first_landmark"] = (
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
    p = ScriptParser(description=__doc__.splitlines()[0])
    p.add_argument("dataset_dir")
    p.add_argument("--windows", nargs="+", default=["0:300", "300:300"],
                   help="START:DURATION in seconds after the latest odometry start")
    p.add_argument("--landmarks", nargs="+", type=int, default=[8, 16],
                   help="landmarks to corrupt, one case each")
    p.add_argument("--cases", nargs="+",
                   default=["clean", "biased_landmark", "misidentified", "turn_bursts",
                            "kidnapped"])
    p.add_argument("--estimators", nargs="+", default=["ekf", "ekf_team"])
    p.add_argument("--kidnap", nargs="+", type=int, default=[1],
                   help="robots to start off their pose, one case each")
    p.add_argument("--kidnap-offset", nargs=2, type=float, default=list(KIDNAP_OFFSET),
                   metavar=("DX", "DY"), help="how far off (m)")
    p.add_argument("--bias-m", type=float, default=BIAS_M, help="biased landmark's offset (m)")
    p.add_argument("--mislabel", choices=sorted(MISLABEL), default="far",
                   help="misidentified landmark: read as one of another cluster, or a neighbour")
    p.add_argument("--late-s", type=float, default=LATE_S,
                   help="turn bursts: how late the bearings are stamped (s)")
    p.add_argument("--noise-scale", type=float, default=1.0,
                   help="multiply the measurement stds by this, process densities by its square")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    try:
        windows = [tuple(float(x) for x in w.split(":")) for w in args.windows]
        if any(len(w) != 2 or not (w[0] >= 0 and w[1] > 0) for w in windows):
            raise ValueError
    except ValueError:
        print(f"--windows takes START:DURATION pairs (START >= 0, DURATION > 0), got "
              f"{args.windows!r}", file=sys.stderr)
        return 2
    try:
        data = load_mrclam(args.dataset_dir)
    except (OSError, ValueError) as err:
        print(f"cannot read the dataset: {err}", file=sys.stderr)
        return 2
    bad = [lm for lm in args.landmarks if lm not in data.landmarks]
    if bad:
        print(f"--landmarks: no such landmark {bad[0]!r}", file=sys.stderr)
        return 2
    if not (np.isfinite(args.noise_scale) and args.noise_scale > 0):
        print(f"--noise-scale must be > 0, got {args.noise_scale!r}", file=sys.stderr)
        return 2
    f = args.noise_scale
    params = scale_noise(load_noise_parameters(), f, f, f * f)
    variants = []
    for case in args.cases:
        if case in ("biased_landmark", "misidentified"):
            variants += [
                (f"{case} {lm}", biased_landmark(data, lm, args.bias_m)
                 if case == "biased_landmark" else misidentified(data, lm, args.mislabel), None)
                for lm in args.landmarks
            ]
        elif case == "turn_bursts":
            variants.append((case, turn_bursts(data, args.late_s), None))
        elif case == "kidnapped":
            bad = [r for r in args.kidnap if r not in data.robot_ids]
            if bad:
                print(f"--kidnap: no such robot {bad[0]!r}", file=sys.stderr)
                return 2
            variants += [(f"{case} {r}", data, r) for r in args.kidnap]
        elif case == "clean":
            variants.append((case, data, None))
        else:
            print(f"unknown case {case!r}", file=sys.stderr)
            return 2
    out = {}
    for start, duration in windows:
        for name, d, kidnap in variants:
            for est in args.estimators:
                key = f"{start:g}:{duration:g} {name} {est}"
                out[key] = run_case(d, est, params, start, duration, kidnap,
                                    tuple(args.kidnap_offset))
                print(key, json.dumps(out[key]), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
