"""scripts/train.py's messages: a missing or corrupt --resume, and the cloning it starts with."""

from __future__ import annotations

import zipfile

from policies.learning.training import TrainConfig, estimate_cloning_s


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_resume_of_a_missing_file_says_it_is_missing(tmp_path, capsys, script_main):
    for scenario in ("outdoor_terrain", "rendezvous"):  # rendezvous clones by default
        rc = script_main("train")(["--scenario", scenario, "--resume",
                                   str(tmp_path / "missing.zip"), "--out", str(tmp_path / "o")])
        assert rc == 2
        assert one_error_line(capsys) == (
            f"error: resume: {str(tmp_path / 'missing.zip')!r} does not exist (give a "
            f"checkpoint .zip or a training run's DIR)")


def test_resume_of_a_corrupt_file_is_one_clean_line(tmp_path, capsys, script_main):
    bad = tmp_path / "corrupt.zip"
    bad.write_text("not a zip")
    assert script_main("train")(["--resume", str(bad), "--out", str(tmp_path / "o")]) == 2
    line = one_error_line(capsys)
    assert line == (f"error: resume: {str(bad)!r} is not a stable-baselines3 checkpoint (not "
                    f"a zip archive)")
    with zipfile.ZipFile(bad, "w") as z:  # a zip, but not a model
        z.writestr("junk.txt", "x")
    rc = script_main("train")(["--resume", str(bad), "--out", str(tmp_path / "o"),
                               "--timesteps", "10", "--no-progress", "--eval-freq", "0"])
    assert rc == 2
    line = one_error_line(capsys)
    assert line.startswith(f"error: resume: cannot load {str(bad)!r} as a PPO model: ")
    assert "Error:" not in line


def test_resume_drops_the_scenarios_cloning_unless_asked(script_module):
    train = script_module("train")
    assert train.parse_args(["--scenario", "rendezvous", "--out", "x"]).bc_from == "gather"
    args = train.parse_args(["--scenario", "rendezvous", "--resume", "r.zip", "--out", "x"])
    cfg = train.config_from_args(args)
    assert cfg.bc_from is None and cfg.dagger_rounds == 0
    args = train.parse_args(["--scenario", "rendezvous", "--resume", "r.zip", "--bc-from",
                             "gather", "--out", "x"])
    assert train.config_from_args(args).bc_from == "gather"


def test_train_says_when_cloning_starts_and_its_cost(tmp_path, capsys, script_main):
    main = script_main("train")
    calls = []

    def fake_train(cfg):  # the cloning notice must come before training starts
        calls.append(capsys.readouterr().out)
        raise ValueError("stop here")

    main.__globals__["train"] = fake_train
    main.__globals__["estimate_cloning_s"] = lambda cfg: 75.4
    assert main(["--scenario", "rendezvous", "--timesteps", "2000",
                 "--out", str(tmp_path / "o")]) == 2
    assert len(calls) == 1 and calls[0].endswith(
        "\nbehaviour cloning gather before PPO: 16 episodes and 4 DAgger rounds, about 75 s to "
        "collect here, plus the fits (--bc-from none skips it)\n")


def test_the_cloning_estimate_scales_one_timed_episode():
    cfg = TrainConfig(out="", scenario="rendezvous", bc_from="gather", bc_episodes=3,
                      dagger_rounds=1, overrides={"max_cycles": 10})
    est = estimate_cloning_s(cfg)
    assert 0 < est < 60  # six 10-step episodes
    cfg2 = TrainConfig(out="", scenario="rendezvous", bc_from="gather", bc_episodes=30,
                       dagger_rounds=1, overrides={"max_cycles": 10})
    assert estimate_cloning_s(cfg2) > 2 * est  # ten times the episodes (timing noise aside)
