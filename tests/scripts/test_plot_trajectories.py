"""scripts/plot_trajectories.py: a figure from a short episode, one-line errors."""

from __future__ import annotations

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "plot_trajectories.py"
spec = importlib.util.spec_from_file_location("plot_trajectories", SCRIPT)
plot_trajectories = importlib.util.module_from_spec(spec)
spec.loader.exec_module(plot_trajectories)


def test_writes_the_figure_with_walls(tmp_path):
    out = tmp_path / "paths.png"
    rc = plot_trajectories.main(["--scenario", "active_hallway", "--policies", "corridor,still",
                                 "--set", "max_cycles=3", "--set", "n_particles=200",
                                 "--out", str(out)])
    assert rc == 0 and out.stat().st_size > 1000


def test_bad_policy_is_one_line_and_exit_2(tmp_path, capsys):
    rc = plot_trajectories.main(["--scenario", "active_hallway", "--policies", "nonsense",
                                 "--out", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert rc == 2 and "nonsense" in err and len(err.strip().splitlines()) == 1
