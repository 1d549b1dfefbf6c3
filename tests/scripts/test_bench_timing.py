"""The timing helper of the MCL benchmark: identical env copies, alternating cases."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_timed_steps_reports_each_case_and_the_gathers():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        from _bench_mcl_team import timed_steps
    finally:
        sys.path.pop(0)
    out = timed_steps("outdoor_terrain", {"ekf": {"estimator": "ekf"},
                                          "mcl": {"estimator": "mcl", "n_particles": 50}},
                      steps=4, warmup=1, copies=2, gather_n=500, tables=(2**10, 2**12),
                      block=2, n_robots=2)
    for label in ("ekf", "mcl"):
        assert 0 < out[label] <= out[label + "_all"]  # the fastest copy, then the mean
    assert out["gather_us_1024"] > 0 and out["gather_us_4096"] > 0
    assert set(out) == {"ekf", "ekf_all", "mcl", "mcl_all", "gather_us_1024", "gather_us_4096"}
