"""BenchMARL tasks shipped in the package: YAML, hydra's search path, logging, a tiny MAPPO."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict

import coop_loc_env
from coop_loc_env.benchmarl import INFO_NAME, CoopLocClass, CoopLocTask


def test_one_task_per_shipped_scenario_with_its_yaml():
    assert [t.name.lower() for t in CoopLocTask] == coop_loc_env.list_scenarios()
    for task in CoopLocTask:
        loaded = task.get_from_yaml()
        assert loaded.config["max_cycles"] == coop_loc_env.make_config(
            task.name.lower()).max_cycles
        assert loaded.supports_continuous_actions() and not loaded.supports_discrete_actions()


def test_task_env_specs_and_a_team_written_as_dicts():
    task = CoopLocTask.RENDEZVOUS.get_task(
        {"max_cycles": 6, "n_particles": 100,
         "team": [{"estimator": "ekf"}, {"estimator": "mcl", "has_gps": False}]})
    env = task.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    assert env.batch_size == torch.Size([3])  # BenchMARL's num_envs worlds in one env
    assert task.group_map(env) == {"robot": [f"robot_{i}" for i in range(4)]}
    assert task.max_steps(env) == 6
    assert list(task.observation_spec(env)["robot"].keys()) == ["observation"]
    assert "particle_spread" in task.info_spec(env)["robot", INFO_NAME].keys()
    td = env.rollout(10)
    assert td.batch_size == torch.Size([3, 6])
    spread = td["next", "robot", INFO_NAME, "particle_spread"]
    assert torch.isnan(spread[..., 0]).all() and torch.isfinite(spread[..., 1]).all()
    assert env.env.config.estimators == ("ekf", "mcl", "ekf", "mcl")
    with pytest.raises(ValueError, match="continuous"):
        task.get_env_fun(num_envs=1, continuous_actions=False, seed=0, device="cpu")


def test_hydra_finds_the_tasks_through_the_package_plugin():
    from benchmarl.hydra_config import load_task_config_from_hydra
    from hydra import compose, initialize_config_module

    with initialize_config_module(config_module="benchmarl.conf", version_base=None):
        cfg = compose(config_name="config", overrides=[
            "algorithm=mappo", "task=coop_loc/active_hallway", "task.max_cycles=30"])
    task = load_task_config_from_hydra(cfg.task, "coop_loc/active_hallway")
    assert isinstance(task, CoopLocClass) and task.name == "ACTIVE_HALLWAY"
    assert task.config["max_cycles"] == 30


def test_log_info_is_nan_aware_and_counts_steps_to_localize():
    # two robots over 8 steps: robot 1 runs no particle filter (NaN); episodes end after
    # steps 1, 4 and 7, so two whole episodes (steps 2-4 and 5-7) start inside the batch
    err = torch.tensor([[3.0, 0.2], [2.0, 2.0], [2.0, 2.0], [1.0, 2.0], [2.0, 2.0],
                        [2.0, 1.4], [1.2, 1.0], [0.5, 0.5]])
    spread = torch.stack([torch.full((8,), 0.4), torch.full((8,), math.nan)], 1)
    done = torch.zeros(8, 1, dtype=torch.bool)
    done[[1, 4, 7]] = True
    info = TensorDict({"position_error": err, "particle_spread": spread,
                       "coverage": torch.full((8, 2), 0.25)}, batch_size=(8, 2))
    batch = TensorDict({"next": {"robot": {INFO_NAME: info}, "done": done}}, batch_size=(8,))
    logged = CoopLocClass.log_info(batch)
    prefix = "collection/robot/info/"
    assert logged[prefix + "particle_spread"] == pytest.approx(0.4)
    assert logged[prefix + "coverage"] == pytest.approx(0.25)
    assert logged[prefix + "position_error"] == pytest.approx(err.mean().item())
    # episode 2-4: robot 0 within 1.5 m at its 2nd step, robot 1 never (its 3 steps count);
    # episode 5-7: robot 0 at its 2nd step, robot 1 at its 1st
    assert logged[prefix + "steps_to_localize"] == pytest.approx((2 + 3 + 2 + 1) / 4)


def test_a_tiny_mappo_run_on_rendezvous(tmp_path):
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models import MlpConfig

    torch.set_num_threads(1)
    task = CoopLocTask.RENDEZVOUS.get_from_yaml()
    task.config.update(max_cycles=50)
    cfg = ExperimentConfig.get_from_yaml()
    cfg.sampling_device = cfg.train_device = "cpu"
    cfg.max_n_frames = 1200
    cfg.on_policy_collected_frames_per_batch = 600
    cfg.on_policy_n_envs_per_worker = 2
    cfg.on_policy_n_minibatch_iters = 1
    cfg.on_policy_minibatch_size = 200
    cfg.evaluation = False
    cfg.loggers = []
    cfg.checkpoint_interval = 0
    cfg.create_json = False
    cfg.render = False
    cfg.save_folder = str(tmp_path)
    returns = []
    for _ in range(2):  # same seed, same returns
        exp = Experiment(task=task, algorithm_config=MappoConfig.get_from_yaml(),
                         model_config=MlpConfig.get_from_yaml(), seed=0, config=cfg)
        exp.run()
        assert exp.total_frames == 1200
        returns.append(exp.mean_return)
    assert math.isfinite(returns[0]) and returns[0] == returns[1]


def _compose(overrides):
    from hydra import compose, initialize_config_module

    with initialize_config_module(config_module="benchmarl.conf", version_base=None):
        return compose(config_name="config", overrides=overrides, return_hydra_config=True)


def test_coop_loc_tasks_log_to_csv_and_check_the_loggers():
    cfg = _compose(["algorithm=mappo", "task=coop_loc/rendezvous"])
    assert list(cfg.experiment.loggers) == ["csv"]  # BenchMARL's own default adds wandb
    assert cfg.experiment.max_n_frames == 3_000_000  # the full run is BenchMARL's
    assert cfg.hydra.callbacks.coop_loc_check_loggers._target_ == (
        "coop_loc_env.benchmarl.hydra_callbacks.CheckLoggers")
    assert "defaults" not in cfg.task and dict(cfg.task) == {"max_cycles": 400}
    cfg = _compose(["algorithm=mappo", "task=coop_loc/rendezvous",
                    "experiment.loggers=[csv,tensorboard]"])
    assert list(cfg.experiment.loggers) == ["csv", "tensorboard"]  # the command line wins


def test_the_short_preset_is_a_few_small_iterations():
    cfg = _compose(["algorithm=mappo", "task=coop_loc/rendezvous",
                    "experiment=coop_loc_short"]).experiment
    assert cfg.max_n_frames == 6000 and cfg.on_policy_collected_frames_per_batch == 2000
    assert cfg.on_policy_n_minibatch_iters == 4 and list(cfg.loggers) == ["csv"]
    assert cfg.evaluation_interval % cfg.on_policy_collected_frames_per_batch == 0
    assert cfg.lr == _compose(["algorithm=mappo", "task=coop_loc/rendezvous"]).experiment.lr


def test_a_missing_logger_package_stops_the_run_in_one_line(capsys, monkeypatch):
    from omegaconf import OmegaConf

    from coop_loc_env.benchmarl import hydra_callbacks

    monkeypatch.setitem(hydra_callbacks.LOGGER_PACKAGES, "wandb", "no_such_package_here")
    check = hydra_callbacks.CheckLoggers()
    check.on_job_start(OmegaConf.create({"experiment": {"loggers": ["csv"]}}))
    with pytest.raises(SystemExit) as stop:
        check.on_job_start(OmegaConf.create({"experiment": {"loggers": ["csv", "wandb"]}}))
    assert stop.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "needs no_such_package_here" in err[0]
    assert "experiment.loggers=[csv]" in err[0]


def test_the_one_line_command_runs_with_the_short_preset(tmp_path):
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    cmd = [sys.executable, "-m", "benchmarl.run", "algorithm=mappo", "task=coop_loc/rendezvous",
           "experiment=coop_loc_short",  # cut further for the test:
           "experiment.max_n_frames=200", "experiment.on_policy_collected_frames_per_batch=200",
           "experiment.on_policy_minibatch_size=100", "experiment.evaluation_interval=200",
           "task.max_cycles=50", f"hydra.run.dir={tmp_path}"]
    done = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "wandb" not in done.stderr
    rewards = list(tmp_path.rglob("eval_reward_episode_reward_mean.csv"))
    assert len(rewards) == 1 and rewards[0].read_text().strip()
