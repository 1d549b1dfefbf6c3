"""Stored reference of the MR.CLAM replay of the bundled excerpt (``tests/data/mrclam_excerpt``).

``tests/estimators/test_mrclam_reference.py`` replays the :data:`CASES` (every
estimator of :func:`estimators.log_replay.replay` and its options) and compares
them with ``tests/data/mrclam_reference.json``: the accepted and rejected
readings and the relocalizations per robot exactly, and the estimates at a
tight tolerance, through an exact hash of the estimate and covariance arrays
and, per robot and block of :data:`BLOCK` grid times, the mean estimated
position, heading (as cos, sin) and position variance. When a change is *meant*
to alter the replay, regenerate the file and commit it with the change:

    python tests/estimators/mrclam_reference.py
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

DATA = Path(__file__).resolve().parents[1] / "data"
EXCERPT = DATA / "mrclam_excerpt"
REFERENCE_PATH = DATA / "mrclam_reference.json"
BLOCK = 20  # grid times (1 s apart) per stored block
ATOL = 1e-8  # m, rad, m^2: far below any change of the models, far above the last bits
KIDNAP = (3.0, -2.0)  # m, added to the kidnapped robot's start estimate


class Case(NamedTuple):
    """One replay: ``options`` go to :func:`~estimators.log_replay.replay`; ``kidnap``
    starts that robot's estimate ``KIDNAP`` off; ``recover_after`` is the team EKF's
    (``None``: the relocalizer off)."""

    estimator: str
    options: dict
    kidnap: int | None = None
    recover_after: int | None = 3


CASES: dict[str, Case] = {
    "dead_reckoning": Case("dead_reckoning", {"duration": 100.0}),
    "ekf": Case("ekf", {"duration": 100.0}),
    "ekf_team": Case("ekf_team", {"duration": 100.0}),
    "ekf_team_no_landmarks": Case("ekf_team", {"duration": 100.0, "use_landmarks": False}),
    "ekf_team_no_screen": Case("ekf_team", {"duration": 100.0, "screen_landmarks": False}),
    "ekf_team_late_start": Case("ekf_team", {"duration": 60.0, "start_offset": 30.0,
                                             "grid_step": 0.5}),
    "ekf_kidnapped": Case("ekf", {"duration": 100.0}, kidnap=3),
    "ekf_team_kidnapped": Case("ekf_team", {"duration": 100.0}, kidnap=3),
    "ekf_team_kidnapped_no_relocalizer": Case("ekf_team", {"duration": 100.0}, kidnap=3,
                                              recover_after=None),
    "mle": Case("mle", {"duration": 12.0}),
}


def run(case: Case, dataset=None, params=None) -> dict[str, Any]:
    """Replay ``case``: its :class:`~estimators.replay.runner.ReplayResult` and the
    relocalizations of its team EKF (``None`` for the MLE)."""
    import estimators.replay.runner as runner
    from estimators.log_replay import load_noise_parameters, replay
    from estimators.mrclam import load_mrclam

    dataset = load_mrclam(EXCERPT) if dataset is None else dataset
    params = load_noise_parameters() if params is None else params
    lost = None if case.kidnap is None else dataset.robot_ids.index(case.kidnap)
    made = []
    original = runner.TeamEKF

    class Watched(original):
        """The replay's team EKF, kidnapped and with the case's relocalizer, kept."""

        def __init__(self, tracks, mean, cov, t0, *args, **kw):
            mean = np.array(mean, dtype=float)
            if lost is not None:
                mean[lost, :2] += KIDNAP
            super().__init__(tracks, mean, cov, t0, *args,
                             **{**kw, "recover_after": case.recover_after})
            made.append(self)

    runner.TeamEKF = Watched
    try:
        result = replay(dataset, case.estimator, params, **case.options)
    finally:
        runner.TeamEKF = original
    relocalizations = None
    if case.estimator != "mle":
        relocalizations = made[-1].relocalizer.recoveries
    return {"result": result, "relocalizations": relocalizations}


def summary(out: dict[str, Any]) -> dict[str, Any]:
    """What is stored of one replay (see the module docstring)."""
    res = out["result"]
    est = np.ascontiguousarray(res.estimate, dtype=np.float64)
    cov = np.ascontiguousarray(res.cov, dtype=np.float64)
    per = np.concatenate([est[..., :2], np.cos(est[..., 2:]), np.sin(est[..., 2:]),
                          (cov[..., 0, 0] + cov[..., 1, 1])[..., None]], axis=-1)
    blocks = [per[:, s:s + BLOCK].mean(axis=1) for s in range(0, per.shape[1], BLOCK)]
    err = np.hypot(*(res.estimate[..., :2] - res.truth[..., :2]).transpose(2, 0, 1))
    return {
        "robots": list(res.robot_ids),
        "grid": [float(res.times[0]), float(res.times[-1]), len(res.times)],
        "accepted": res.accepted.tolist(),
        "rejected": res.rejected.tolist(),
        "relocalizations": out["relocalizations"],
        "measurements": int(res.info["measurements_in_window"]),
        "sha256": hashlib.sha256(est.tobytes() + cov.tobytes()).hexdigest()[:32],
        # per block (robot, [x, y, cos, sin, var_x + var_y]) means
        "blocks": [np.round(b, 12).tolist() for b in blocks],
        "final": np.round(est[:, -1], 12).tolist(),
        "mean_error_m": [round(float(e), 12) for e in np.where(res.valid, err, 0).sum(axis=1)
                         / np.maximum(res.valid.sum(axis=1), 1)],
    }


def compare(name: str, got: dict[str, Any], want: dict[str, Any]) -> str | None:
    """``None`` when the replay ``got`` matches the stored ``want``; otherwise what differs
    first (counts, then the first block of estimates, then the final poses)."""
    for key in ("robots", "grid", "measurements", "accepted", "rejected", "relocalizations"):
        if got[key] != want[key]:
            return f"{name}: {key} {got[key]} != stored {want[key]}"
    if got["sha256"] == want["sha256"]:
        return None
    labels = ("x", "y", "cos heading", "sin heading", "position variance")
    for b, (g, w) in enumerate(zip(got["blocks"], want["blocks"], strict=True)):
        diff = np.abs(np.asarray(g) - np.asarray(w))
        if (diff > ATOL).any():
            r, q = np.unravel_index(np.argmax(diff), diff.shape)
            t0 = want["grid"][0]
            step = (want["grid"][1] - t0) / max(want["grid"][2] - 1, 1)
            return (f"{name}: grid times {t0 + b * BLOCK * step:.1f}-"
                    f"{t0 + min((b + 1) * BLOCK, want['grid'][2]) * step - step:.1f} s, robot "
                    f"{want['robots'][r]}: mean {labels[q]} {g[r][q]:.9g}, stored {w[r][q]:.9g}")
    diff = np.abs(np.asarray(got["final"]) - np.asarray(want["final"]))
    if (diff > ATOL).any():
        return f"{name}: final poses {got['final']} != stored {want['final']}"
    return None


def main() -> int:
    data = {name: summary(run(case)) for name, case in CASES.items()}
    REFERENCE_PATH.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {REFERENCE_PATH} ({REFERENCE_PATH.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    raise SystemExit(main())
