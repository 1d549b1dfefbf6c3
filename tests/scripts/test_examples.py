"""The examples in examples/ run (with small settings)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def example(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main


def test_custom_scenario_example(capsys, monkeypatch):
    from coop_loc_env import scenarios

    # The example registers its scenario; keep the registry of the other tests as shipped.
    monkeypatch.setattr(scenarios, "_REGISTRY", dict(scenarios._REGISTRY))
    example("custom_scenario")()
    out = capsys.readouterr().out
    assert "('ekf', 'mcl', 'ekf', 'mcl')" in out and out.count("position error") == 4


def test_replay_logs_example(capsys):
    example("replay_logs")([])
    out = capsys.readouterr().out
    assert "dead_reckoning" in out and "ekf_team" in out


def test_evaluate_example(capsys):
    example("evaluate")(["--episodes", "1", "--max-cycles", "5"])
    assert capsys.readouterr().out.count("team localization error (m)") == 3


@pytest.mark.slow
def test_train_example(tmp_path, capsys):
    example("train")(["--timesteps", "512", "--out", str(tmp_path / "run")])
    out = capsys.readouterr().out
    assert "trained 512 agent steps" in out and "learned" in out and "fsm" in out
