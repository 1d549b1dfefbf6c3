"""Time-to-localize statistics: median intervals, the localized-over-time curve, gap closed."""

from __future__ import annotations

import numpy as np
import pytest

from policies.experiments.compare import compare
from policies.experiments.localization_curves import (
    gap_closed,
    localized_curve,
    median_ci,
    plot_localized_curve,
)


def test_median_ci_covers_the_median_and_narrows_with_more_data():
    rng = np.random.default_rng(1)
    small = rng.exponential(10.0, 50)
    big = rng.exponential(10.0, 2000)
    m, lo, hi = median_ci(small)
    assert lo <= m <= hi and m == pytest.approx(np.median(small))
    m2, lo2, hi2 = median_ci(big)
    assert hi2 - lo2 < hi - lo
    assert lo2 < 10.0 * np.log(2) < hi2  # the exponential's true median
    with pytest.raises(ValueError, match="level"):
        median_ci(small, level=1.5)


def test_localized_curve_counts_first_times_and_never_counts_the_unlocalized():
    records = [{"robot_times_to_localize_s": [1.0, 3.0], "robot_localized": [True, True]},
               {"robot_times_to_localize_s": [2.0, 9.0], "robot_localized": [True, False]}]
    curve = localized_curve(records, np.array([0.5, 1.0, 2.5, 3.0, 9.0]))
    np.testing.assert_allclose(curve, [0.0, 0.25, 0.5, 0.75, 0.75])


def test_gap_closed():
    assert gap_closed(20.0, 15.0, 10.0) == pytest.approx(0.5)
    assert gap_closed(20.0, 22.0, 10.0) == pytest.approx(-0.2)
    with pytest.raises(ValueError, match="no gap"):
        gap_closed(10.0, 9.0, 10.0)


def test_compare_records_per_robot_times_and_plots_the_curve(tmp_path):
    rep = compare("active_hallway", ["corridor", "still"], 2, 7,
                  {"n_robots": 2, "n_particles": 200, "max_cycles": 30}, progress=False)
    for spec in ("corridor", "still"):
        for rec in rep["episodes"][spec]:
            times = np.asarray(rec["robot_times_to_localize_s"])
            assert times.shape == (2,) and len(rec["robot_localized"]) == 2
            assert times.mean() == pytest.approx(rec["time_to_localize_s"])
    path = plot_localized_curve(rep, tmp_path / "curve.png", dt=0.5)
    assert path.stat().st_size > 1000
