"""Torch's thread count, chosen in coop_loc_env.threads for every trainer and entry point."""

from __future__ import annotations

import pytest
import torch

import coop_loc_env
from coop_loc_env.threads import THREADS_ENV, TORCH_THREADS, set_torch_threads, torch_threads


@pytest.fixture
def restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_the_project_setting_and_its_override(monkeypatch):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    assert torch_threads() == TORCH_THREADS == 1
    monkeypatch.setenv(THREADS_ENV, "3")
    assert torch_threads() == 3
    monkeypatch.setenv(THREADS_ENV, "0")
    assert torch_threads() is None  # torch's own setting
    for bad in ("-1", "two", "1.5"):
        monkeypatch.setenv(THREADS_ENV, bad)
        with pytest.raises(ValueError, match=THREADS_ENV):
            torch_threads()


def test_set_torch_threads_applies_it_or_leaves_torch_alone(monkeypatch, restore_threads):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    torch.set_num_threads(2)
    assert set_torch_threads() == 1 == torch.get_num_threads()
    monkeypatch.setenv(THREADS_ENV, "2")
    assert set_torch_threads() == 2
    monkeypatch.setenv(THREADS_ENV, "0")
    torch.set_num_threads(3)
    assert set_torch_threads() == 3


def test_the_torchrl_and_benchmarl_entry_points_set_it(monkeypatch, restore_threads):
    from coop_loc_env.benchmarl import CoopLocTask

    monkeypatch.delenv(THREADS_ENV, raising=False)
    torch.set_num_threads(2)
    coop_loc_env.torchrl_env("rendezvous", seed=0, max_cycles=5)
    assert torch.get_num_threads() == 1
    torch.set_num_threads(2)
    monkeypatch.setenv(THREADS_ENV, "3")
    task = CoopLocTask.RENDEZVOUS.get_task({"max_cycles": 5})
    task.get_env_fun(num_envs=1, continuous_actions=True, seed=0, device="cpu")
    assert torch.get_num_threads() == 3


def test_acting_with_a_network_uses_it(monkeypatch, restore_threads):
    from policies.learning.learned import LearnedPolicy

    class Model:  # what LearnedPolicy needs of a stable-baselines3 model
        observation_space = None

        def predict(self, obs, deterministic=True):
            return obs, None

    monkeypatch.setenv(THREADS_ENV, "2")
    torch.set_num_threads(1)
    LearnedPolicy(Model())
    assert torch.get_num_threads() == 2
