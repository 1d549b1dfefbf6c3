"""The timing helper of the MCL benchmark: identical env copies, alternating cases."""

from __future__ import annotations


def test_timed_steps_reports_each_case_and_the_gathers(script_module):
    timed_steps = script_module("bench/mcl_team").timed_steps
    out = timed_steps("outdoor_terrain", {"ekf": {"estimator": "ekf"},
                                          "mcl": {"estimator": "mcl", "n_particles": 50}},
                      steps=4, warmup=1, copies=2, gather_n=500, tables=(2**10, 2**12),
                      block=2, n_robots=2)
    for label in ("ekf", "mcl"):
        assert 0 < out[label] <= out[label + "_all"]  # the fastest copy, then the mean
    assert out["gather_us_1024"] > 0 and out["gather_us_4096"] > 0
    assert set(out) == {"ekf", "ekf_all", "mcl", "mcl_all", "gather_us_1024", "gather_us_4096"}
