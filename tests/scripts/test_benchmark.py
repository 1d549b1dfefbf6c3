"""The env benchmark: env and mpe2 alternating in one process, the ratio and the growth
printed against their targets."""

from __future__ import annotations

import numpy as np
import pytest


def test_benchmark_prints_the_ratio_and_the_growth_against_their_targets(script_main, capsys):
    results = script_main("benchmark")(["--seconds", "0.1", "--rounds", "2", "--sizes", "2", "3",
                                        "--env-only"])
    out = capsys.readouterr().out
    rows = results["env"]
    assert [row["robots"] for row in rows] == [2, 3]
    for row in rows:
        assert len(row["rounds"]) == 2
        for r in row["rounds"]:  # each round's ratio is its own two rates
            assert r["steps_per_s"] > 0 and r["mpe2_steps_per_s"] > 0
            assert r["ratio"] == pytest.approx(r["steps_per_s"] / r["mpe2_steps_per_s"])
    assert len(results["growth_rounds"]) == 2 and min(results["growth_rounds"]) > 0
    assert results["growth"] == pytest.approx(float(np.median(results["growth_rounds"])))
    assert f"ratio to mpe2 at 2 robots: {rows[0]['ratio']:.2f}" in out
    assert "target >= 1.5, at least 1.1" in out
    assert "step time at 3 robots" in out and "target <= 6x)" in out


@pytest.mark.parametrize("argv", [["--seconds", "0"], ["--rounds", "0"], ["--sizes", "4", "0"]])
def test_benchmark_refuses_bad_arguments_in_one_line(script_main, capsys, argv):
    assert script_main("benchmark")(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --")
