"""``scripts/evaluate.py --compare``: confidence intervals, time to localize, table, plot, JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

from policies.experiments.compare import (
    compare,
    episode_time_to_localize,
    format_compare_table,
    mean_ci,
    merge_reports,
    parse_policy_list,
)


def test_mean_ci_is_the_student_t_interval():
    v = np.array([1.0, 2.0, 3.0, 4.0])
    m, lo, hi = mean_ci(v)
    # t(0.975, 3) = 3.182446, s = 1.290994, n = 4
    half = 3.182446 * 1.290994 / 2
    assert m == 2.5
    assert lo == pytest.approx(2.5 - half, rel=1e-5) and hi == pytest.approx(2.5 + half, rel=1e-5)
    m, lo, hi = mean_ci(np.array([5.0]))
    assert m == 5.0 and np.isnan(lo) and np.isnan(hi)


def test_mean_ci_is_clipped_to_the_bounds():
    counts = np.array([0.0, 0.0, 0.0, 12.0])  # the t interval reaches below 0
    m, lo, hi = mean_ci(counts)
    assert lo < 0
    m_b, lo_b, hi_b = mean_ci(counts, bounds=(0.0, np.inf))
    assert (m_b, lo_b, hi_b) == (m, 0.0, hi)
    frac = np.array([1.0, 1.0, 1.0, 0.5])
    assert mean_ci(frac)[2] > 1.0
    assert mean_ci(frac, bounds=(0.0, 1.0))[2] == 1.0


def test_time_to_localize_first_crossing_and_censoring():
    std = np.full((10, 2), 5.0)
    std[4:, 0] = 1.0  # robot 0: spread sqrt(2) * 1.0 = 1.41 < 1.5 from step index 4
    ep = {"series": {"position_std_m": std}}
    t, frac = episode_time_to_localize(ep, dt=0.1)
    assert t == pytest.approx((0.5 + 1.0) / 2)  # robot 1 never: counted as the episode length
    assert frac == 0.5
    std[4:, 0] = 1.1  # spread 1.556 > 1.5: not localized
    assert episode_time_to_localize(ep, dt=0.1) == (pytest.approx(1.0), 0.0)


def test_parse_policy_list_rejects_bad_lists():
    assert parse_policy_list("fsm, random,a/b.zip") == ["fsm", "random", "a/b.zip"]
    for bad in ("", "fsm,,random", "fsm,fsm"):
        with pytest.raises(ValueError):
            parse_policy_list(bad)


def test_evaluate_compare_prints_one_table_and_saves_plot_and_json(tmp_path, capsys, script_main,
                                                                   monkeypatch):
    out = tmp_path / "cmp.json"
    evaluate = script_main("evaluate")
    written = {}  # what each JSON path held when written (the partial one is then removed)
    write_json = evaluate.__globals__["write_json"]

    def spy(data, path):
        written[path.name] = json.loads(json.dumps(data, default=str))
        return write_json(data, path)

    monkeypatch.setitem(evaluate.__globals__, "write_json", spy)
    rc = evaluate(["--compare", "fsm,random", "--episodes", "3", "--max-cycles", "15",
                   "--set", "n_robots=2", "--seed", "4", "--json", str(out),
                   "--plot-dir", str(tmp_path), "--no-progress"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "mean [95 % CI] over 3 episodes (seeds 4..6)" in text
    assert text.count("\nfsm ") == 1 and text.count("\nrandom ") == 1
    # DGPS localizes every robot from the first step: time to localize says nothing here
    assert "time to localize left out" in text and "time to localize (s)" not in text
    assert "paired difference in team loc. error (m) vs fsm" in text
    data = json.loads(out.read_text())
    assert data["policies"] == ["fsm", "random"]
    partial = written["cmp.partial.json"]  # saved after fsm, removed once the whole run is
    assert not (tmp_path / "cmp.partial.json").exists()
    assert partial["policies"] == ["fsm"] and partial["summary"]["fsm"] == data["summary"]["fsm"]
    for spec in ("fsm", "random"):
        errs = [ep["localization_error_m"] for ep in data["episodes"][spec]]
        assert [ep["seed"] for ep in data["episodes"][spec]] == [4, 5, 6]
        s = data["summary"][spec]["localization_error_m"]
        assert s["mean"] == pytest.approx(np.mean(errs))
        assert s["low"] < s["mean"] < s["high"]
    assert (tmp_path / "outdoor_terrain_compare.png").stat().st_size > 10_000
    assert evaluate(["--compare", "fsm,nonsense", "--no-progress"]) == 2
    assert "unknown policy 'nonsense'" in capsys.readouterr().err


def test_particle_spread_is_used_when_present():
    std = np.full((4, 1), 0.1)  # covariance says localized from the start
    spread = np.array([[3.0], [2.0], [1.0], [0.5]])  # particles: localized at step 3
    ep = {"series": {"position_std_m": std, "particle_spread_m": spread}}
    assert episode_time_to_localize(ep, dt=0.5) == (pytest.approx(1.5), 1.0)


def test_localized_at_end_counts_a_lost_belief_out():
    from policies.experiments.compare import localized_at_end

    # robot 0 localizes and stays; robot 1 localizes at step 2 and loses it again
    spread = np.array([[3.0, 3.0], [1.0, 1.0], [0.5, 9.0]])
    ep = {"series": {"position_std_m": np.zeros((3, 2)), "particle_spread_m": spread}}
    assert episode_time_to_localize(ep, dt=0.5) == (pytest.approx(1.0), 1.0)
    assert localized_at_end(ep) == 0.5


def test_compare_records_mcl_particle_spread_and_runs_wander():
    data = compare("symmetric_hallway", ["wander"], 1, seed=0,
                   overrides={"max_cycles": 3, "n_robots": 2, "n_particles": 200},
                   progress=False)
    rec = data["episodes"]["wander"][0]
    assert rec["steps"] == 3
    # global localization from a uniform belief: not localized after 1.5 s
    assert rec["localized_fraction"] == 0.0 and rec["time_to_localize_s"] == pytest.approx(1.5)
    assert rec["localized_at_end"] == 0.0


def test_still_policy_covers_less_than_random():
    data = compare("outdoor_terrain", ["still", "random"], 1, seed=2,
                   overrides={"max_cycles": 30, "n_robots": 2}, progress=False)
    still, rand = (data["episodes"][s][0] for s in ("still", "random"))
    assert still["collisions"] == 0 and still["coverage"] < rand["coverage"]
    # the same comparison run as two reports and merged gives the same table
    kw = dict(n_episodes=1, seed=2, overrides={"max_cycles": 30, "n_robots": 2}, progress=False)
    parts = [compare("outdoor_terrain", [s], **kw) for s in ("still", "random")]
    merged = merge_reports(parts)
    assert format_compare_table(merged) == format_compare_table(data)
    with pytest.raises(ValueError, match="more than one report"):
        merge_reports([parts[0], parts[0]])


def test_localized_from_the_start():
    from policies.experiments.compare import localized_from_the_start

    at_start = {"time_to_localize_s": 0.5, "localized_fraction": 1.0}
    later = {"time_to_localize_s": 3.0, "localized_fraction": 1.0}
    assert localized_from_the_start({"episodes": {"a": [at_start], "b": [at_start]}}, dt=0.5)
    assert not localized_from_the_start({"episodes": {"a": [at_start], "b": [later]}}, dt=0.5)
    never = {"time_to_localize_s": 0.5, "localized_fraction": 0.5}
    assert not localized_from_the_start({"episodes": {"a": [never]}}, dt=0.5)
