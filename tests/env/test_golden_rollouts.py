"""Behaviour regression: short seeded episodes must match the stored rollouts.

If a change is meant to alter behaviour, regenerate the data with
``python tests/env/golden_rollouts.py`` and commit it with the change.
"""

from __future__ import annotations

import numpy as np
import pytest
from golden_rollouts import CASES, GOLDEN_PATH, rollout

# Floating-point reassociation (BLAS builds, numpy versions) moves the last bits;
# any change of a model, noise constant or seed use moves far more than this.
RTOL, ATOL = 1e-7, 1e-9


@pytest.fixture(scope="module")
def golden():
    with np.load(GOLDEN_PATH) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.parametrize("case", sorted(CASES))
def test_rollout_matches_stored(case, golden):
    scenario, overrides, seed, steps = CASES[case]
    got = rollout(scenario, overrides, seed, steps)
    for key, value in got.items():
        expected = golden[f"{case}/{key}"]
        assert value.shape == expected.shape, f"{case}/{key}: shape {value.shape}"
        np.testing.assert_allclose(
            value, expected, rtol=RTOL, atol=ATOL, equal_nan=True,
            err_msg=f"{case}/{key} differs from the stored rollout "
            "(regenerate with `python tests/env/golden_rollouts.py` if intended)",
        )


def test_cases_cover_every_scenario_and_estimator():
    import coop_loc_env
    from coop_loc_env.config import ESTIMATORS
    from coop_loc_env.scenarios import make_config

    scenarios = {scenario for scenario, _, _, _ in CASES.values()}
    assert scenarios == set(coop_loc_env.list_scenarios())
    estimators = {make_config(s, **o).estimator for s, o, _, _ in CASES.values()}
    assert estimators == set(ESTIMATORS)


def test_every_subsystem_is_exercised(golden):
    """The stored arrays are not blank: some case sees camera records refined by depth
    from motion, grows the map, and runs MCL and MLE filters."""
    camera = [golden[f"{c}/camera"] for c in CASES]
    assert sum(float(a[..., 0].sum()) for a in camera) > 50  # records
    assert max(float((a[..., 4] - a[..., 0]).max()) for a in camera) > 0  # tracks > 1 frame
    for case in CASES:
        mapped = golden[f"{case}/map"][:, 0]
        assert mapped[-1] > mapped[0] > 0, case
    mcl = [c for c in CASES if np.isfinite(golden[f"{c}/mcl"]).any()]
    mle = [c for c in CASES if np.isfinite(golden[f"{c}/mle"]).any()]
    assert {c.split("_")[0] for c in mcl} == {"mcl"}
    assert {c.split("_")[0] for c in mle} == {"mle"}
    assert len(mcl) >= 3 and len(mle) >= 3
