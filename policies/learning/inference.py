"""What acting with a trained network needs, for both backends (SB3 and RLlib).

The torch thread count for acting, the check that a network fits an env's
observations, and which backend saved a run.
"""

from __future__ import annotations

from pathlib import Path

from gymnasium import spaces

INFERENCE_THREADS = 1
"""Torch threads for acting: a forward pass of one team observation is too small to gain
from more (on a shared 2-core machine, 14.0-27.3 ms per predict with torch's default of 2
threads vs 0.96-1.08 ms with 1: ``python scripts/bench/inference.py``)."""


def check_observation_shape(name: str, expected, env) -> None:
    """Raise ``ValueError`` unless ``env``'s observations fit a network's: ``expected`` is
    its observation space (a ``Box`` or a ``Dict`` of them) or a ``Box``'s shape."""
    got = env.observation_space(env.possible_agents[0])
    want_dict = isinstance(expected, spaces.Dict)
    if want_dict or isinstance(got, spaces.Dict):
        shapes = {k: s.shape for k, s in expected.spaces.items()} if want_dict else None
        have = {k: s.shape for k, s in got.spaces.items()} if isinstance(
            got, spaces.Dict) else None
        if shapes != have:
            raise ValueError(
                f"model {name!r} expects observations {shapes or _shape(expected)}, the env "
                f"gives {have or got.shape}: use the same scenario/config overrides as in "
                f"training (obs_format, belief_map_cells, ...)"
            )
        return
    if tuple(_shape(expected)) != tuple(got.shape):
        raise ValueError(
            f"model {name!r} expects observations of shape {_shape(expected)}, the env "
            f"gives {got.shape}: use the same scenario/config overrides as in training"
        )


def _shape(space_or_shape) -> tuple:
    return tuple(getattr(space_or_shape, "shape", space_or_shape))


def is_rllib_run(path: str | Path) -> bool:
    """Whether ``path`` is an RLlib run ``DIR`` (holding ``checkpoint/``) or checkpoint."""
    path = Path(path)
    return (path / "checkpoint" / "rllib_checkpoint.json").is_file() or (
        path / "rllib_checkpoint.json"
    ).is_file()
