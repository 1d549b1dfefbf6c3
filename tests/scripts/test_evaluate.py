"""scripts/evaluate.py end to end, and the runner library under it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from policies.episode import FIGURES
from policies.experiments.report import summarize
from policies.experiments.runner import parse_overrides, run_episodes
from policies.learning.learned import SB3Policy, detect_sb3_algo
from policies.learning.loader import make_policy


def test_evaluate_writes_valid_json_and_plots(tmp_path, capsys, script_main,
                                              mean_position_error):
    out = tmp_path / "eval.json"
    rc = script_main("evaluate")(
        ["--scenario", "outdoor_terrain", "--policy", "fsm", "--episodes", "2", "--max-cycles",
         "40", "--seed", "5", "--json", str(out), "--plot-dir", str(tmp_path), "--set",
         "n_robots=2", "--no-progress"]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["scenario"] == "outdoor_terrain" and data["policy"] == "fsm"
    assert [ep["seed"] for ep in data["episodes"]] == [5, 6]
    assert all(ep["steps"] == 40 for ep in data["episodes"])
    assert set(data["summary"]) == set(FIGURES)
    for key in FIGURES:
        vals = [ep[key] for ep in data["episodes"]]
        assert data["summary"][key]["mean"] == pytest.approx(np.mean(vals))
        assert data["summary"][key]["std"] == pytest.approx(np.std(vals))
    assert 0 < data["summary"]["coverage"]["mean"] < 1
    expected = mean_position_error("outdoor_terrain", make_policy("fsm"), [5, 6], n_robots=2,
                                   max_cycles=40)
    assert data["summary"]["localization_error_m"]["mean"] == pytest.approx(expected, rel=1e-12)
    assert sum(data["episodes"][0]["state_steps"].values()) == 2 * 40
    pngs = sorted(p.name for p in tmp_path.glob("*.png"))
    assert pngs == ["outdoor_terrain_fsm_error.png", "outdoor_terrain_fsm_terrain.png"]
    table = capsys.readouterr().out
    assert "team localization error (m)" in table and "+/-" in table


def test_evaluate_rejects_bad_input(capsys, script_main):
    main = script_main("evaluate")
    assert main(["--policy", "nonsense", "--episodes", "1", "--no-progress"]) == 2
    assert "unknown policy 'nonsense'" in capsys.readouterr().err
    assert main(["--set", "n_robots=0", "--episodes", "1", "--no-progress"]) == 2
    assert "n_robots" in capsys.readouterr().err
    assert main(["--set", "nokey", "--no-progress"]) == 2


def test_run_episodes_figures_match_series():
    eps = run_episodes("outdoor_terrain", "random", 1, seed=1,
                       overrides={"max_cycles": 25, "n_robots": 2}, progress=False)
    ep = eps[0]
    err = ep["series"]["position_error_m"]
    assert err.shape == (25, 2)
    assert ep["localization_error_m"] == pytest.approx(np.nanmean(err))
    assert ep["maps"]["estimated"].shape == ep["maps"]["true"].shape
    assert summarize(eps)["coverage"]["std"] == 0.0
    with pytest.raises(ValueError, match="n_episodes"):
        run_episodes("outdoor_terrain", "random", 0)


def test_parse_overrides():
    assert parse_overrides(["n_robots=4", "estimator=ekf", "world_size=(20.0, 20.0)"]) == {
        "n_robots": 4, "estimator": "ekf", "world_size": (20.0, 20.0)}
    with pytest.raises(ValueError, match="KEY=VALUE"):
        parse_overrides(["n_robots"])


def test_saved_sb3_model_is_a_policy(tmp_path):
    import gymnasium
    from stable_baselines3 import PPO

    import coop_loc_env

    env = coop_loc_env.parallel_env(n_robots=2, max_cycles=10)

    class Single(gymnasium.Env):
        observation_space = env.observation_space("robot_0")
        action_space = env.action_space("robot_0")

    path = tmp_path / "ppo_model.zip"
    PPO("MlpPolicy", Single(), n_steps=8, batch_size=8, device="cpu").save(path)
    assert detect_sb3_algo(path) == "PPO"
    policy = make_policy(str(path))
    assert isinstance(policy, SB3Policy)
    eps = run_episodes("outdoor_terrain", policy, 1, overrides={"max_cycles": 10, "n_robots": 2},
                       progress=False)
    assert eps[0]["steps"] == 10
    with pytest.raises(ValueError, match="shape"):
        run_episodes("outdoor_terrain", policy, 1, overrides={"max_cycles": 5, "n_robots": 2,
                                                             "laser_obs_bins": 8},
                      progress=False)
    with pytest.raises(ValueError, match="does not exist"):
        make_policy(str(tmp_path / "missing.zip"))


def test_render_episode_saves_gif(tmp_path, script_main):
    import imageio.v2 as imageio

    main = script_main("render_episode")
    out = tmp_path / "ep.gif"
    assert main(["--policy", "seek", "--max-cycles", "20", "--every", "10", "--out",
                     str(out), "--set", "n_robots=2", "--no-progress"]) == 0
    frames = imageio.mimread(out)
    assert len(frames) == 3  # after reset, step 10, step 20
    assert frames[0].ndim == 3 and frames[0].shape[2] in (3, 4)
    assert not np.array_equal(frames[0], frames[-1])
    assert main(["--every", "0", "--no-progress"]) == 2


def test_one_policy_registry_for_policy_and_compare(capsys, script_main):
    from policies.scripted.registry import policy_names

    assert {"fsm", "random", "seek", "still", "wander"} <= set(policy_names())
    main = script_main("evaluate")
    with pytest.raises(SystemExit):
        main(["--help"])
    help_text = capsys.readouterr().out
    for name in policy_names():
        assert f"\n  {name} " in help_text
    for name in ("still", "wander", "wander:0.8"):  # --compare took these; --policy did not
        assert main(["--policy", name, "--episodes", "1", "--max-cycles", "3",
                     "--set", "n_robots=2", "--no-progress"]) == 0
    assert make_policy("wander:0.8").speed == 0.8
    with pytest.raises(ValueError, match="takes no argument"):
        make_policy("fsm:1")
