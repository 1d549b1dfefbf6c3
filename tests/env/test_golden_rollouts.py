"""Behaviour regression: seeded episodes must match the stored digests.

If a change is meant to alter behaviour, regenerate the data with
``python tests/env/golden_rollouts.py [CASE ...]`` and commit it with the change.
"""

from __future__ import annotations

import numpy as np
import pytest
from golden_rollouts import BLOCK, CASES, EVENTS, compare, digest, figures, load, rollout


@pytest.fixture(scope="module")
def golden():
    return load()["cases"]


@pytest.mark.parametrize("case", list(CASES))
def test_rollout_matches_stored(case, golden):
    got = rollout(CASES[case])
    stored = golden[case]
    problem = compare(case, {k: v for k, v in got.items() if k != "events"},
                      stored["quantities"])
    assert problem is None, problem
    # (the counts of EVENTS are measured against thresholds: recorded, not compared)
    behaviour = {k: v for k, v in figures(got).items() if k not in EVENTS}
    assert behaviour == {k: v for k, v in stored["figures"].items() if k not in EVENTS}, case


def test_stored_file_holds_every_case(golden):
    assert list(golden) == list(CASES)


def test_cases_cover_every_scenario_and_estimator():
    import coop_loc_env
    from coop_loc_env.config import ESTIMATORS
    from coop_loc_env.scenarios import make_config

    scenarios = {c.scenario for c in CASES.values()}
    assert scenarios == set(coop_loc_env.list_scenarios())
    configs = {name: make_config(c.scenario, **c.overrides) for name, c in CASES.items()}
    assert {cfg.estimator for cfg in configs.values()} == set(ESTIMATORS)
    # a long episode (>= 300 steps) of every estimator
    long = {configs[n].estimator for n, c in CASES.items() if c.steps >= 300}
    assert long == set(ESTIMATORS)
    # every particle scenario, and the outdoor one with MCL, at its own particle count
    own = {c.scenario for c in CASES.values()
           if "n_particles" not in c.overrides and make_config(c.scenario, **c.overrides)
           .estimator == "mcl"}
    assert own >= {s for s in coop_loc_env.list_scenarios()
                   if make_config(s).estimator == "mcl"} | {"outdoor_terrain"}
    assert any(cfg.obs_format == "dict" for cfg in configs.values())
    drivers = {c.driver for c in CASES.values()}
    assert {"kidnap", "wall", "policy:hypothesis", "policy:infogain", "policy:fsm",
            "policy:corridor"} <= drivers


def test_every_subsystem_is_exercised(golden):
    """The stored episodes are not blank: some case sees camera records refined by depth
    from motion, grows the map, and runs MCL and MLE filters."""
    fig = {case: golden[case]["figures"] for case in CASES}
    assert sum(f["camera_records"] for f in fig.values()) > 50
    assert sum(f["camera_multi_frame"] for f in fig.values()) > 0  # tracks > 1 frame
    for case, f in fig.items():
        assert f["mapped_start"] > 0, case
        if CASES[case].steps >= 10:
            assert f["mapped_end"] > f["mapped_start"], case
        assert f["steps"] == CASES[case].steps, case  # no episode ended early
    mcl = {c.split("_")[0] for c, f in fig.items() if f["mcl_robots"]}
    mle = {c.split("_")[0] for c, f in fig.items() if f["mle_pairs"]}
    assert "mcl" in mcl and mcl <= {"mcl", "plan"}
    assert mle == {"mle"}


# The fewest of each rare decision the set must contain (sums over the cases; the
# stored counts are several times these).
RARE_EVENTS = {
    "gate_rejections_near": 5,  # within 10 % above the EKF gate's chi-square threshold
    "gate_accepts_near": 5,  # within 10 % below it
    "agreement_near": 1,  # a GateMonitor agreement test within 10 % of its threshold
    "recoveries": 2,  # EKF lock-out recoveries
    "conflicts": 10,  # MCL detections contradicting a confident robot
    "confident_below": 10,  # confident target, Bayes factor below min_bayes_factor
    "confident_above": 10,  # ... above it
    "bayes_factor_near": 5,  # ... within a factor 2 of it
    "mode_mass_near": 5,  # main-mode mass within 10 % of confident_mass
    "multipath_fixes": 20,
    "false_detections": 50,
}


@pytest.mark.parametrize("event", list(RARE_EVENTS))
def test_rare_branches_are_reached(event, golden):
    total = sum(golden[case]["figures"][event] for case in CASES)
    assert total >= RARE_EVENTS[event], f"{event}: {total} in the whole set"


def test_recoveries_come_from_a_kidnapped_robot():
    """The lock-out recovery runs where a robot was carried off (the kidnapped case), and
    not in the same episode without the kidnapping."""
    kidnapped = CASES["ekf_kidnapped"]
    got = rollout(kidnapped)
    steps = np.nonzero(got["events"][:, EVENTS.index("recoveries")])[0]
    assert len(steps) and steps.min() > kidnapped.steps // 3
    calm = rollout(kidnapped._replace(driver="random"))
    assert calm["events"][:, EVENTS.index("recoveries")].sum() == 0


def test_a_difference_is_reported_with_its_case_step_range_and_quantity():
    rng = np.random.default_rng(0)
    got = {"obs": rng.normal(size=(80, 3, 4)), "cov": rng.normal(size=(80, 3))}
    stored = {k: digest(v) for k, v in got.items()}
    assert compare("somecase", got, stored) is None
    moved = dict(got, cov=got["cov"].copy())
    moved["cov"][60, 1] += 1e-5
    message = compare("somecase", moved, stored)
    assert message is not None
    assert "somecase" in message and "cov" in message and "obs" not in message
    assert f"steps {2 * BLOCK}-{3 * BLOCK - 1}" in message
    # the last bits (another BLAS build) are tolerated
    close = dict(got, obs=got["obs"] * (1 + 1e-12))
    assert compare("somecase", close, stored) is None
    # a new NaN is reported as such
    nan = dict(got, obs=got["obs"].copy())
    nan["obs"][5, 0, 0] = np.nan
    assert "non-finite" in compare("somecase", nan, stored)
