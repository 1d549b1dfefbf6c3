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
