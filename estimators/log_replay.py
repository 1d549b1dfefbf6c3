"""Replay of logged multi-robot data: the names of :mod:`estimators.replay`, importable
from their former module (see that package for the protocol)."""

from estimators.replay import (
    DEFAULT_NOISE_PATH,
    ESTIMATORS,
    PER_ROBOT_KEYS,
    TUNING_GRID,
    NoiseParameters,
    ReplayResult,
    evaluate,
    fit_noise_parameters,
    load_noise_parameters,
    replay,
    save_noise_parameters,
    scale_noise,
    tune_inflation,
)

__all__ = [
    "ESTIMATORS",
    "DEFAULT_NOISE_PATH",
    "PER_ROBOT_KEYS",
    "TUNING_GRID",
    "NoiseParameters",
    "ReplayResult",
    "evaluate",
    "fit_noise_parameters",
    "load_noise_parameters",
    "replay",
    "save_noise_parameters",
    "scale_noise",
    "tune_inflation",
]
