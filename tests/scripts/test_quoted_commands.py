"""The commands whose output the docs quote: the belief-honesty probes,
``scripts/run_episode.py`` and ``scripts/plot_training.py``."""

from __future__ import annotations

import functools
import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
EXCERPT = ROOT / "tests" / "data" / "mrclam_excerpt"


@pytest.fixture
def belief_honesty():
    """The module of ``scripts/bench/belief_honesty.py``."""
    path = ROOT / "scripts" / "bench" / "belief_honesty.py"
    spec = importlib.util.spec_from_file_location("belief_honesty", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_belief_honesty_probes_on_a_few_steps(belief_honesty, monkeypatch, tmp_path, capsys):
    """The command's plumbing (each probe printed and written to --json) on short runs,
    with figures in the range a short run of today's code gives."""
    short = {
        "forward": functools.partial(belief_honesty.forward, seeds=(0,), steps=100),
        "half_gps": functools.partial(belief_honesty.half_gps, seeds=range(2), steps=50),
        "wall": functools.partial(belief_honesty.wall, blocked_s=10.0, free_s=10.0),
    }
    monkeypatch.setattr(belief_honesty, "PROBES", {**belief_honesty.PROBES, **short})
    out = tmp_path / "honesty.json"
    assert belief_honesty.main(["--json", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    data = json.loads(out.read_text())
    assert [line.split()[0] for line in printed] == list(data) == ["forward", "half_gps", "wall"]
    for line in printed:
        name, _, figures = line.partition(" ")
        assert json.loads(figures) == data[name]
    forward, wall = data["forward"], data["wall"]
    # Bands: max + 3 sd of each figure over seeds 0-15 of the same short forward run
    # (share above the bound 0-0.05, sd 0.012; median 0.10-0.29 m, sd 0.048; max
    # 0.67-1.49 m, sd 0.23), over the 8 seed pairs (0, 1) .. (14, 15) of the short
    # half-GPS run (0.016-0.393 m, sd 0.16), and the wall run's seeds 0-7 (below the
    # bound at every blocked step, below 0.5 m 0.1 s after leaving, in all 8).
    assert forward["samples"] == 400 and forward["nees_above_bound"] <= 0.09
    assert forward["median_error_m"] < 0.43 and forward["max_error_m"] < 2.2
    assert data["half_gps"]["max_error_rise_m"] < 0.87
    assert wall["blocked_steps"] > 50 and wall["blocked_nees_below_bound"] == 1.0
    assert wall["seconds_to_below_0.5m_after_leaving"] <= 1.0


def test_belief_honesty_figures_quoted_in_the_docs(belief_honesty, tmp_path):
    """The full default run (the command in docs/estimators.md) gives the figures quoted
    there to their quoted precision."""
    out = tmp_path / "honesty.json"
    assert belief_honesty.main(["--json", str(out)]) == 0
    data = json.loads(out.read_text())
    page = (ROOT / "docs" / "estimators.md").read_text()
    sentence = " ".join(page[page.index("Figures (outdoor_terrain, 4"):].split()[:80])
    quoted = re.search(
        r"([\d.]+) % of belief samples above the 99\.9 % NEES bound, median error ([\d.]+) m, "
        r"max ([\d.]+) m.*below 0\.5 m ([\d.]+) s after leaving the wall.*error is ([\d.]+) m",
        sentence,
    )
    assert quoted, sentence
    share, median, peak, leave_s, rise = (float(v) for v in quoted.groups())
    forward = data["forward"]
    assert round(100 * forward["nees_above_bound"], 1) == share
    assert round(forward["median_error_m"], 2) == median
    assert round(forward["max_error_m"], 1) == peak
    assert data["wall"]["blocked_nees_below_bound"] == 1.0  # "at every blocked step"
    assert data["wall"]["seconds_to_below_0.5m_after_leaving"] == pytest.approx(leave_s)
    assert round(data["half_gps"]["max_error_rise_m"], 2) == rise


def test_belief_honesty_kidnapped_log_on_the_excerpt(belief_honesty):
    """Robot 1 started 3.6 m off: the gate lock-out recovery rejects fewer of its readings
    and leaves it no further off than without (60 s of the excerpt: 2 vs 22 rejected
    readings with ekf, 23 vs 50 with ekf_team)."""
    out = belief_honesty.kidnapped_log(str(EXCERPT), duration=60.0)
    for est in ("ekf", "ekf_team"):
        on, off = out[f"{est} recover_after=3"], out[f"{est} recover_after=None"]
        assert on["rejected"][0] < off["rejected"][0]
        assert on["robot1_mean_error_m"] <= off["robot1_mean_error_m"]
        assert len(on["rejected"]) == 5


def test_belief_honesty_kidnapped_log_needs_a_dataset(belief_honesty, capsys):
    assert belief_honesty.main(["--probe", "kidnapped_log"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["--probe kidnapped_log needs --mrclam DATASET"]


def test_run_episode_prints_each_robots_error_and_saves_a_frame(script_module, tmp_path,
                                                                capsys):
    mod = script_module("run_episode")
    frame = tmp_path / "out" / "frame.png"
    assert mod.main(["--steps", "6", "--seed", "2", "--frame", str(frame)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "outdoor_terrain: 6 steps, seed 2"
    assert lines[-1] == f"frame saved to {frame}"
    printed = [float(m.group(1)) for line in lines[1:-1]
               if (m := re.fullmatch(r"  robot_\d+: mean position error ([\d.]+) m", line))]
    assert len(printed) == len(lines) - 2 == 3
    expected = mod.run("outdoor_terrain", 6, 2, None)  # the same episode without a frame
    np.testing.assert_allclose(printed, list(expected.values()), atol=5e-4)
    import imageio.v2 as imageio

    image = imageio.imread(frame)
    assert image.ndim == 3 and image.shape[2] in (3, 4) and image.std() > 0


def test_run_episode_bad_step_count_is_one_line_and_exit_2(script_module, tmp_path, capsys):
    mod = script_module("run_episode")
    assert mod.main(["--steps", "0", "--frame", str(tmp_path / "f.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "max_cycles" in err[0] and "got 0" in err[0]


def _training_run(path: Path, returns: list[float]) -> Path:
    """A training directory as ``scripts/train.py`` leaves it: TensorBoard log, summary
    with periodic evaluations and a baseline, and the config naming the baseline."""
    from tensorboard.compat.proto.event_pb2 import Event
    from tensorboard.compat.proto.summary_pb2 import Summary
    from tensorboard.summary.writer.event_file_writer import EventFileWriter

    writer = EventFileWriter(str(path / "tb" / "PPO_1"))
    for step, value in enumerate(returns):
        scalar = Summary(value=[Summary.Value(tag="rollout/ep_rew_mean", simple_value=value)])
        writer.add_event(Event(step=1000 * step, wall_time=float(step), summary=scalar))
    writer.close()
    summary = {"evals": [{"timesteps": 0, "localization_error_m": 1.2},
                         {"timesteps": 4000, "localization_error_m": 0.9}],
               "baseline": {"localization_error_m": 1.0}}
    (path / "train_summary.json").write_text(json.dumps(summary))
    (path / "train_config.json").write_text(json.dumps({"eval_baseline": "gather"}))
    return path


def test_plot_training_reads_the_log_and_writes_the_figure(script_module, tmp_path, capsys):
    mod = script_module("plot_training")
    run = _training_run(tmp_path / "run", [-5.0, -4.0, -3.5, -2.0])
    steps, values = mod.tb_scalars(run / "tb", "rollout/ep_rew_mean")
    assert steps == [0, 1000, 2000, 3000] and values == [-5.0, -4.0, -3.5, -2.0]
    out = tmp_path / "figs" / "training.png"
    assert mod.main(["--run", str(run), "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out}"
    import imageio.v2 as imageio

    image = imageio.imread(out)
    assert image.shape[:2] == (272, 720)  # 9 x 3.4 inches at 80 dpi
    assert mod.main(["--run", str(tmp_path / "missing"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing" in err[0]
