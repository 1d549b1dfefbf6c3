"""What acting with a trained network needs, for both backends (SB3 and RLlib).

The torch thread count for acting, the check that a network fits an env's
observations, and which backend saved a run.
"""

from __future__ import annotations

from pathlib import Path

from gymnasium import spaces

from coop_loc_env.threads import TORCH_THREADS

INFERENCE_THREADS = TORCH_THREADS
"""Torch threads for acting (the project's :data:`~coop_loc_env.threads.TORCH_THREADS`,
overridden by ``COOP_LOC_TORCH_THREADS``): a forward pass of one team observation is too
small to gain from more (on a shared 2-core machine, 14.0-27.3 ms per predict with
torch's default of 2 threads vs 0.96-1.08 ms with 1: ``python scripts/bench/inference.py``)."""


def check_observation_shape(name: str, expected, env) -> None:
    """Raise ``ValueError`` unless ``env``'s observations fit a network's: ``expected`` is
    its observation space (a ``Box`` or a ``Dict`` of them) or a ``Box``'s shape."""
    want = _layout(expected)
    got = _layout(env.observation_space(env.possible_agents[0]))
    if want != got:
        raise ValueError(
            f"model {name!r} expects observations of shape {want}, the env gives {got}: use "
            f"the same scenario/config overrides as in training (obs_format, "
            f"belief_map_cells, ...)"
        )


def _layout(space_or_shape) -> tuple | dict[str, tuple]:
    """A space's shape, or a ``Dict`` space's shape per key."""
    if isinstance(space_or_shape, spaces.Dict):
        return {k: tuple(s.shape) for k, s in space_or_shape.spaces.items()}
    return tuple(getattr(space_or_shape, "shape", space_or_shape))


def is_rllib_run(path: str | Path) -> bool:
    """Whether ``path`` is an RLlib run ``DIR`` (holding ``checkpoint/``) or checkpoint."""
    path = Path(path)
    return (path / "checkpoint" / "rllib_checkpoint.json").is_file() or (
        path / "rllib_checkpoint.json"
    ).is_file()
