"""What acting with a trained network needs, for both backends (SB3 and RLlib).

The torch thread count for acting, the check that a network fits an env's
observations, and which backend saved a run.
"""

from __future__ import annotations

from pathlib import Path

INFERENCE_THREADS = 1
"""Torch threads for acting: a forward pass of one team observation is too small to gain
from more (on a shared 2-core machine, 14.0-27.3 ms per predict with torch's default of 2
threads vs 0.96-1.08 ms with 1: ``python scripts/bench/inference.py``)."""


def check_observation_shape(name: str, expected: tuple, env) -> None:
    """Raise ``ValueError`` unless ``env``'s observations have the ``expected`` shape."""
    got = env.observation_space(env.possible_agents[0]).shape
    if tuple(expected) != tuple(got):
        raise ValueError(
            f"model {name!r} expects observations of shape {expected}, the env "
            f"gives {got}: use the same scenario/config overrides as in training"
        )


def is_rllib_run(path: str | Path) -> bool:
    """Whether ``path`` is an RLlib run ``DIR`` (holding ``checkpoint/``) or checkpoint."""
    path = Path(path)
    return (path / "checkpoint" / "rllib_checkpoint.json").is_file() or (
        path / "rllib_checkpoint.json"
    ).is_file()
