"""The batched env's benchmark: the sides alternate, the ratios are the rounds' own."""

from __future__ import annotations

import pytest


def test_measure_reports_each_side_and_the_ratios_of_the_rounds(script_module, monkeypatch):
    bench = script_module("bench/vector_env")
    rates = iter(range(1, 100))
    monkeypatch.setattr(bench, "_rate", lambda step, seconds: float(next(rates)))
    for side in ("_ours", "_torchrl"):  # the sides' stepping: the next test
        monkeypatch.setattr(bench, side, lambda b: None)
    monkeypatch.setattr(bench, "_single", lambda: None)
    monkeypatch.setattr(bench, "_vmas", lambda b, threads: (lambda: b))
    out = bench.measure([1, 4], seconds=0.01, rounds=2, torchrl=True)
    # per round: single, ours_B1, torchrl_B1, vmas_B1, ours_B4, torchrl_B4, vmas_B4
    assert out["single"] == 4.5 and out["ours_B4"] == 8.5 and out["vmas_B4"] == 10.5
    assert out["ours_B4_over_single"] == pytest.approx((5 / 1 + 12 / 8) / 2)
    assert out["ours_B4_over_vmas"] == pytest.approx((5 / 7 + 12 / 14) / 2)
    assert out["torchrl_B1_step_ratio"] == pytest.approx((2 / 3 + 9 / 10) / 2)
    assert out["vmas_installed"]


def test_every_side_steps_its_worlds(script_module):
    bench = script_module("bench/vector_env")
    assert bench._ours(3)() == 3 and bench._single()() == 1 and bench._torchrl(2)() == 2
    assert bench._vmas(5, threads=1)() == 5
    assert bench._sb3("batched", 2)() == 8 and bench._sb3("copies", 2)() == 8
    assert bench._serial_torchrl(2)() == 2


@pytest.mark.parametrize("argv", [["--sizes", "0"], ["--seconds", "0"],
                                  ["--scenario", "nope"]])
def test_bad_arguments_refused_in_one_line(script_module, capsys, argv):
    assert script_module("bench/vector_env").main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ")
