"""The mode reliability bench (``scripts/bench/mode_reliability.py``): bins, meetings, errors."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def bench(script_module):
    return script_module("bench/mode_reliability")


def test_weights_fall_in_the_documented_bins(bench):
    w = np.array([0.2, 0.5, 0.59, 0.6, 0.85, 0.9, 0.989, 0.99, 1.0])
    labels = [bench.BIN_LABELS[b] for b in bench.weight_bin(w)]
    assert labels == ["<0.5", "0.5-0.6", "0.5-0.6", "0.6-0.7", "0.8-0.9", "0.9-0.99",
                      "0.9-0.99", ">=0.99", ">=0.99"]


def test_wilson_interval_brackets_the_fraction(bench):
    lo, hi = bench.wilson(50, 100)
    assert lo == pytest.approx(0.404, abs=1e-3) and hi == pytest.approx(0.596, abs=1e-3)
    assert bench.wilson(0, 0) == (0.0, 1.0)
    assert bench.wilson(10, 10)[1] == 1.0


def test_a_top_mode_is_right_within_a_metre_and_0_3_rad(bench):
    truth = np.array([[5.0, 5.0, 0.0]] * 4)
    modes = np.zeros((4, 2, 6))
    for i, (dx, dh) in enumerate([(0.9, 0.0), (1.1, 0.0), (0.0, 0.29), (0.0, 0.31)]):
        modes[i, 0] = [0.9, 5.0 + dx, 5.0, np.cos(dh), np.sin(dh), 0.1]
    assert bench.top_mode_right(modes, truth).tolist() == [True, False, True, False]
    modes[0, 0, 0] = 0.0  # no mode at all is never right
    assert not bench.top_mode_right(modes, truth)[0]


def test_episode_figures_bins_honesty_and_meetings(bench):
    steps, dt = 6, 0.5
    weight = np.array([[0.95, 0.55]] * steps)
    right = np.array([[True, False]] * steps)
    right[:3, 0] = False  # robot 0's 0.9-0.99 mode is right 3 times of 6
    std = np.full((steps, 2), 2.0)
    std[1, 1] = 0.5
    err = np.full((steps, 2), 5.0)  # one confident-and-wrong sample: robot 1 at step 1
    spread = np.array([[0.5, 3.0]] * steps)
    spread[4:, 1] = 1.0  # robot 1 localized at row 4 ...
    spread[0, 0] = 2.0  # robot 0 localized at row 1
    # ... met by robot 0 (global index 10) at row 2; robot 1's state then: 0.55, wrong
    meets = [(2, 10, 11), (3, 10, 11), (2, 11, 10)]
    ep = bench.reduce_episode(7, weight, right, std, err, spread, meets, [10, 11], dt)
    bins = dict(zip(bench.BIN_LABELS, ep["bins"], strict=True))
    assert bins["0.9-0.99"][:2] == [6, 3] and bins["0.5-0.6"][:2] == [6, 0]
    assert ep["confident_wrong"] == 1 and ep["lost"] == 0 and ep["localized"] == 2
    assert ep["time_to_localize_s"] == [1.0, 2.5]
    # one meeting (the first, not the repeated one; robot 0 was localized when met)
    assert ep["meetings"] == [{"wrong_confident": False, "meet_to_localized_s": 1.0,
                               "localized": True}]
    out = bench.summarize([ep])
    top = next(b for b in out["bins"] if b["bin"] == "0.9-0.99")
    assert top["right"] == 0.5 and top["gap"] == pytest.approx(0.5 - 0.95)
    assert out["max_abs_gap"] == pytest.approx(0.55)
    assert out["meetings"]["all"]["robots"] == 1
    assert "0.9-0.99 | 6 | 0.950 | 0.500" in bench.format_table(out)


def test_a_met_robot_holding_a_wrong_mode_at_0_9_is_counted_apart(bench):
    weight = np.array([[1.0, 0.95]] * 4)
    right = np.array([[True, False]] * 4)
    spread = np.array([[0.5, 3.0]] * 4)
    ep = bench.reduce_episode(0, weight, right, np.ones((4, 2)), np.zeros((4, 2)), spread,
                              [(1, 0, 1)], [0, 1], 1.0)
    assert ep["meetings"] == [{"wrong_confident": True, "meet_to_localized_s": 2.0,
                               "localized": False}]
    assert ep["lost"] == 0 and ep["localized"] == 1


def test_set_extras_goes_over_the_scenario_extras(bench):
    import coop_loc_env

    base = coop_loc_env.make_config("active_hallway").extras
    got = bench.with_scenario_extras("active_hallway", {"n_robots": 2,
                                                        "extras": {"mcl_calibrated_copies": True}})
    assert got == {"n_robots": 2, "extras": {**base, "mcl_calibrated_copies": True}}
    assert bench.with_scenario_extras("active_hallway", {"n_robots": 2}) == {"n_robots": 2}


@pytest.mark.parametrize("argv", [["--episodes", "0"], ["--scenario", "nowhere"],
                                  ["--policy", "nonesuch"], ["--set", "extras=3"],
                                  ["--set", "extras={mcl_calibrated_copies: 1}"]])
def test_bad_arguments_are_refused_in_one_line(bench, capsys, argv):
    assert bench.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0]
