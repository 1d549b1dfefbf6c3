"""Run the team EKF on real robot logs (UTIAS MR.CLAM) and compare with dead reckoning.

    python examples/replay_logs.py [DATASET_DIR]

Without an argument it uses the 100 s excerpt shipped in tests/data/mrclam_excerpt.
The full datasets (MRCLAM_Dataset1..9) are at
http://asrl.utias.utoronto.ca/datasets/mrclam/ ; unpack one and pass its folder.
``scripts/replay_logs.py`` does the same with more options (MLE, noise fitting, plots).
"""

from __future__ import annotations

import sys
from pathlib import Path

from estimators.log_replay import evaluate, load_noise_parameters, replay
from estimators.mrclam import load_mrclam

EXCERPT = Path(__file__).resolve().parents[1] / "tests" / "data" / "mrclam_excerpt"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    dataset = load_mrclam(argv[0] if argv else EXCERPT)
    params = load_noise_parameters()  # fitted on MR.CLAM dataset 6, shipped with the package
    duration = min(60.0, dataset.end_time() - dataset.latest_odometry_start())
    for estimator in ("dead_reckoning", "ekf_team"):
        m = evaluate(replay(dataset, estimator, params, duration=duration))
        print(f"{estimator:15s} mean position error {m['mean_position_error_m']:.3f} m, "
              f"final {m['final_position_error_m']:.3f} m over {duration:.0f} s")


if __name__ == "__main__":
    main()
