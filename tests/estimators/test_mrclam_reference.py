"""The MR.CLAM replay of the bundled excerpt must match its stored reference.

If a change is meant to alter the replay, regenerate the reference with
``python tests/estimators/mrclam_reference.py`` and commit it with the change.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from mrclam_reference import CASES, EXCERPT, REFERENCE_PATH, compare, run, summary

from estimators.log_replay import load_noise_parameters
from estimators.mrclam import load_mrclam


@pytest.fixture(scope="module")
def reference():
    return json.loads(REFERENCE_PATH.read_text())


@pytest.fixture(scope="module")
def dataset():
    return load_mrclam(EXCERPT)


@pytest.fixture(scope="module")
def params():
    return load_noise_parameters()


@pytest.mark.parametrize("case", list(CASES))
def test_replay_matches_the_stored_reference(case, reference, dataset, params):
    got = summary(run(CASES[case], dataset, params))
    problem = compare(case, got, reference[case])
    assert problem is None, problem


def test_the_reference_covers_every_estimator_and_the_relocalizer(reference):
    from estimators.replay.runner import ESTIMATORS

    assert list(reference) == list(CASES)
    assert {c.estimator for c in CASES.values()} == set(ESTIMATORS)
    # the relocalizer runs on the kidnapped robot, and without it the robot stays lost
    on, off = reference["ekf_team_kidnapped"], reference["ekf_team_kidnapped_no_relocalizer"]
    assert on["relocalizations"] >= 1 and off["relocalizations"] == 0
    lost = on["robots"].index(3)
    assert off["mean_error_m"][lost] > 5 * on["mean_error_m"][lost]
    assert sum(off["rejected"]) > sum(on["rejected"])


def test_a_difference_names_the_case_the_time_span_and_the_robot(reference):
    want = reference["ekf"]
    got = json.loads(json.dumps(want))
    got["sha256"] = "0" * 32
    got["blocks"][2][1][0] += 1e-6
    message = compare("ekf", got, want)
    assert message is not None and "ekf" in message and "robot 2" in message
    t0 = want["grid"][0]
    assert f"{t0 + 40:.1f}-{t0 + 59:.1f} s" in message
    got["blocks"][2][1][0] -= 1e-6 - 1e-12  # the last bits are tolerated
    assert compare("ekf", got, want) is None
    got["rejected"] = [1, 0, 0, 0, 0]
    assert "rejected" in compare("ekf", got, want)
    assert np.isfinite(want["final"]).all()
