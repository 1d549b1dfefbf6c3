"""Estimator backends: one registry, one base class with no-op defaults."""

from __future__ import annotations

import math

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env import backends
from coop_loc_env.backends import backend_class, register_backend
from coop_loc_env.backends.base import EstimatorBackend
from coop_loc_env.backends.ekf import EKFBackend
from coop_loc_env.backends.mcl import MCLBackend
from coop_loc_env.backends.mle import MLEBackend


def test_builtin_backends_resolve_by_name_and_share_the_base_class():
    assert backend_class("ekf") is EKFBackend
    assert backend_class("mcl") is MCLBackend
    assert backend_class("mle") is MLEBackend
    assert all(issubclass(c, EstimatorBackend) for c in (EKFBackend, MCLBackend, MLEBackend))
    with pytest.raises(ValueError, match="'ukf'.*available: ekf, mcl, mle"):
        backend_class("ukf")


def test_base_class_defaults_are_no_ops():
    assert EstimatorBackend.feature_names == ()
    assert EstimatorBackend().extra_info(np.zeros((2, 3))) == {}


def test_a_registered_backend_is_built_and_its_extra_info_reaches_the_infos(monkeypatch):
    # A new name (removed again afterwards): the config accepts every registered estimator.
    monkeypatch.setitem(backends.BACKENDS, "tagged_ekf", EKFBackend)

    @register_backend("tagged_ekf")
    class TaggedEKF(EKFBackend):
        def extra_info(self, true_poses):
            return {0: {"tag": 1.0}}

    env = coop_loc_env.parallel_env(max_cycles=2, estimator="tagged_ekf")
    _, infos = env.reset(seed=0)
    assert isinstance(env.backends[0], TaggedEKF)
    assert infos["robot_0"]["tag"] == 1.0
    assert math.isnan(infos["robot_1"]["tag"])  # every agent gets the same keys
