"""The seed-level bootstrap behind the Fox reproduction's intervals."""

from __future__ import annotations

import numpy as np
import pytest

from policies.experiments.fox import bootstrap_over_seeds


def test_bootstrap_interval_covers_the_mean_and_shrinks_with_more_seeds():
    rng = np.random.default_rng(0)
    widths = []
    for n in (8, 128):
        x = rng.normal(10.0, 2.0, size=n)
        lo, hi = bootstrap_over_seeds({"x": x}, lambda d: float(d["x"].mean()), n_boot=4000)
        assert lo < x.mean() < hi
        widths.append(hi - lo)
        # the normal-theory 95 % half-width is 1.96 sigma / sqrt(n)
        assert hi - lo == pytest.approx(2 * 1.96 * x.std(ddof=1) / np.sqrt(n), rel=0.25)
    assert widths[1] < widths[0] / 2


def test_bootstrap_keeps_conditions_paired():
    # "with" is always "without" minus 5: any resample of whole seeds gives exactly 5
    base = np.random.default_rng(1).uniform(20, 200, size=16)
    lo, hi = bootstrap_over_seeds({"a": base, "b": base - 5.0},
                                  lambda d: float((d["a"] - d["b"]).mean()), n_boot=500)
    assert lo == pytest.approx(5.0) and hi == pytest.approx(5.0)


def test_bootstrap_rejects_unequal_seed_counts():
    with pytest.raises(ValueError, match="same number"):
        bootstrap_over_seeds({"a": np.ones(3), "b": np.ones(4)}, lambda d: 0.0)
