"""``--config FILE.yaml`` and YAML ``--set`` values in the scripts, the shipped example
configs, and one-line errors (bad YAML, unknown key, bad value, bad arguments)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import coop_loc_env
from coop_loc_env.cli import parse_overrides, parse_value
from coop_loc_env.config_file import load_config_file

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "examples" / "configs").glob("*.yaml"))


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def test_the_shipped_configs_load_and_build_their_scenario():
    assert {p.name for p in CONFIGS} >= {"mixed_team.yaml", "gps_denied_rendezvous.yaml",
                                         "noisy_sensors.yaml"}
    for path in CONFIGS:
        loaded = load_config_file(path)
        assert loaded.scenario in coop_loc_env.list_scenarios(), path
        loaded.check(loaded.scenario)


def test_evaluate_runs_the_heterogeneous_team_config(tmp_path, capsys, script_main):
    path = ROOT / "examples" / "configs" / "mixed_team.yaml"
    loaded = load_config_file(path)
    cfg = coop_loc_env.make_config(loaded.scenario, **loaded.overrides)
    assert cfg.estimators == ("ekf", "mcl", "ekf", "ekf")
    assert [cfg.robot_spec(i).has_gps for i in range(4)] == [True, False, False, True]
    assert cfg.robot_spec(2).range_sensor == "sonar"
    out = tmp_path / "eval.json"
    rc = script_main("evaluate")(["--config", str(path), "--policy", "seek", "--episodes", "1",
                                  "--max-cycles", "5", "--no-progress", "--json", str(out)])
    assert rc == 0, capsys.readouterr().err
    data = json.loads(out.read_text())
    assert data["scenario"] == "outdoor_terrain" and data["episodes"][0]["steps"] == 5


def test_set_and_scenario_apply_on_top_of_the_file(script_module):
    train = script_module("train")
    args = train.parse_args(["--config", str(ROOT / "examples/configs/mixed_team.yaml"),
                             "--set", "n_robots=2", "--set", "team=[{estimator: ekf}]",
                             "--out", "x"])
    cfg = train.config_from_args(args)
    assert cfg.scenario == "outdoor_terrain"
    assert cfg.overrides["n_robots"] == 2 and cfg.overrides["team"] == [{"estimator": "ekf"}]
    assert cfg.overrides["n_particles"] == 300  # the file's, untouched by --set
    args = train.parse_args(["--config", str(ROOT / "examples/configs/mixed_team.yaml"),
                             "--scenario", "rendezvous", "--out", "x"])
    assert train.config_from_args(args).scenario == "rendezvous"
    # the scenario named in the file picks its training defaults (rendezvous clones gather)
    args = train.parse_args(["--config", str(ROOT / "examples/configs/gps_denied_rendezvous"
                                                    ".yaml"), "--out", "x"])
    assert args.bc_from == "gather"


def test_set_values_are_python_literals_or_yaml():
    assert parse_overrides(["team=[{estimator: ekf}, {estimator: mcl, has_gps: false}]"]) == {
        "team": [{"estimator": "ekf"}, {"estimator": "mcl", "has_gps": False}]}
    assert parse_overrides(["n_robots=4", "world_size=(20.0, 20.0)", "estimator=ekf",
                            "team=[{'estimator': 'mle'}]", "extras={'mcl_x': None}"]) == {
        "n_robots": 4, "world_size": (20.0, 20.0), "estimator": "ekf",
        "team": [{"estimator": "mle"}], "extras": {"mcl_x": None}}
    assert parse_value("true") is True and parse_value("False") is False
    assert parse_value("[1, 2") == "[1, 2"  # neither: the string itself
    assert parse_value("off") == "off" and parse_value("yes") == "yes"  # words, not YAML 1.1 bools
    cfg = coop_loc_env.make_config("rendezvous", **parse_overrides(["team=[{estimator: ekf}]"]))
    assert set(cfg.estimators) == {"ekf"}


@pytest.mark.parametrize("text, line, key, words", [
    ("scenario: rendezvous\nn_robots: [1,\n", 3, "n_robots", "bad YAML"),
    ("scenario: rendezvous\nteam: [{estimator: ekf}\nn_robots: 3\n", 3, "team", "bad YAML"),
    ("scenario: rendezvous\nn_robot: 4\n", 2, "n_robot", "did you mean 'n_robots'"),
    ("scenario: rendezvous\nmax_cycles: 10\nteam:\n  - {estimator: nope}\n", 3, "team",
     "registered estimator"),
    ("n_robots: -3\n", 1, "n_robots", "n_robots must be"),
    ("scenario: nowhere\n", 1, "scenario", "unknown scenario"),
    ("scenario: rendezvous\nmax_cycles: 10\nmax_cycles: 20\n", 3, "max_cycles", "given twice"),
])
def test_a_bad_file_gives_one_line_naming_file_line_and_key(tmp_path, capsys, script_main,
                                                            text, line, key, words):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    for name in ("evaluate", "run_episode", "render_episode"):
        assert script_main(name)(["--config", str(path), "--no-progress"][
            : 2 if name == "run_episode" else 3]) == 2
        msg = one_error_line(capsys)
        assert msg.startswith(f"error: {path}:{line}: ") and repr(key) in msg and words in msg


def test_train_names_the_file_too(tmp_path, capsys, script_main):
    path = tmp_path / "bad.yaml"
    path.write_text("scenario: rendezvous\nn_robot: 4\n")
    assert script_main("train")(["--config", str(path), "--out", str(tmp_path / "o")]) == 2
    assert one_error_line(capsys).startswith(f"error: {path}:2: key 'n_robot'")


def test_a_missing_or_non_mapping_file(tmp_path, capsys, script_main):
    assert script_main("evaluate")(["--config", str(tmp_path / "none.yaml")]) == 2
    assert one_error_line(capsys) == f"error: {tmp_path / 'none.yaml'}: no such config file"
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    assert script_main("evaluate")(["--config", str(tmp_path / "list.yaml")]) == 2
    assert "expected a mapping" in one_error_line(capsys)


def test_run_episode_takes_a_config_and_set(tmp_path, capsys, script_main):
    rc = script_main("run_episode")(["--config", str(ROOT / "examples/configs/mixed_team.yaml"),
                                     "--set", "n_robots=3", "--steps", "3", "--frame",
                                     str(tmp_path / "f.png")])
    assert rc == 0
    out = capsys.readouterr().out
    assert out.startswith("outdoor_terrain: 3 steps") and "robot_2" in out
    assert "robot_3" not in out and (tmp_path / "f.png").is_file()


@pytest.mark.parametrize("name, argv", [
    ("run_episode", ["--steps", "many"]),
    ("replay_logs", ["tests/data/mrclam_excerpt", "--estimator", "nope"]),
    ("plot_trajectories", ["--policies", "gather"]),
    ("evaluate", ["--episodes"]),
])
def test_bad_arguments_give_one_line(capsys, script_main, name, argv):
    with pytest.raises(SystemExit) as stop:
        script_main(name)(argv)
    assert stop.value.code == 2
    line = one_error_line(capsys)
    assert ": error: " in line and line.endswith("(see --help)")
