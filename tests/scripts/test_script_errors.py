"""Scripts on bad input: one line on stderr naming what is wrong, exit status 2."""

from __future__ import annotations

import importlib
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXCERPT = ROOT / "tests" / "data" / "mrclam_excerpt"


def script(name: str):
    """The module of ``scripts/NAME.py``."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.pop(0)


def run_failing(capsys, name: str, argv: list[str]) -> str:
    """Run ``scripts/NAME.py`` with ``argv``, expect exit status 2; return its stderr line."""
    assert script(name).main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


@pytest.fixture
def dataset_copy(tmp_path: Path) -> Path:
    dst = tmp_path / "mrclam"
    shutil.copytree(EXCERPT, dst)
    return dst


def test_replay_logs_missing_folder(capsys, tmp_path: Path):
    line = run_failing(capsys, "replay_logs", [str(tmp_path / "nowhere"), "--no-progress"])
    assert "nowhere" in line


def test_replay_logs_missing_file(capsys, dataset_copy: Path):
    (dataset_copy / "Robot3_Odometry.dat").unlink()
    line = run_failing(capsys, "replay_logs", [str(dataset_copy), "--no-progress"])
    assert "Robot3_Odometry.dat" in line


def test_replay_logs_malformed_line(capsys, dataset_copy: Path):
    path = dataset_copy / "Robot2_Measurement.dat"
    lines = path.read_text().splitlines()
    first_data = next(i for i, t in enumerate(lines) if t.strip() and not t.startswith("#"))
    lines[first_data + 3] = "1.25 abc 3"
    path.write_text("\n".join(lines) + "\n")
    line = run_failing(capsys, "replay_logs", [str(dataset_copy), "--no-progress"])
    assert f"Robot2_Measurement.dat:{first_data + 4}" in line


def test_replay_logs_says_when_the_data_is_shorter_than_duration(capsys, tmp_path: Path):
    out = tmp_path / "m.json"
    rc = script("replay_logs").main([str(EXCERPT), "--estimator", "dead_reckoning",
                                     "--duration", "5000", "--no-progress", "--json", str(out)])
    assert rc == 0
    assert "not the 5000 s of --duration" in capsys.readouterr().out


def test_reproduce_madhavan_runs_longer_than_the_scenario_and_skips_an_empty_plot(
    capsys, tmp_path: Path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    mod = script("reproduce_madhavan")
    # 60 s is 600 steps, past the scenario's max_cycles=500: the episode is made long enough
    assert mod.main(["--duration", "60", "--plot", ""]) == 0
    assert "std_peak_m" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []  # --plot '' writes nothing
    line = run_failing(capsys, "reproduce_madhavan",
                       ["--duration", "60", "--set", "max_cycles=500", "--plot", ""])
    assert "at least 600" in line


def test_reproduce_howard_says_how_to_run_longer(capsys):
    line = run_failing(capsys, "reproduce_howard", ["--experiments", "circuit",
                                                    "--circuit-duration", "200", "--plot", "",
                                                    "--no-progress"])
    assert "--set max_cycles=2000" in line
