"""The features of a dict observation (``obs_format="dict"``): a small CNN on the belief map.

SB3's ``MultiInputPolicy`` sends image-like inputs through its ``NatureCNN``, which
needs ``uint8`` images of at least 36 x 36 pixels; the belief map is float32 mass
on a ``belief_map_cells`` grid (32 a side by default), so it would be flattened
into a 10,000-input MLP instead. :class:`BeliefMapExtractor` is the small
convolutional encoder the active-localization literature uses for the same input
(Chaplot et al.'s Active Neural Localization, Gottipati et al.'s Deep Active
Localization): three stride-2 3 x 3 convolutions, one linear layer, the result
concatenated with the observation's ``"vector"`` as it is (so the MLP heads see
the same vector a flat-observation policy sees).

The mass channels hold values from ``~1e-4`` (a belief spread over the map) to
``~0.3`` (four symmetric modes); the encoder reads their square root, which keeps
both ends in a range a network can weigh (the occupancy channel, a fraction in
``[0, 1]``, stays in it).
"""

from __future__ import annotations

import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

MAP_KEY = "belief_map"
VECTOR_KEY = "vector"


class BeliefMapExtractor(BaseFeaturesExtractor):
    """CNN on ``obs["belief_map"]`` ``(C, H, W)`` joined with ``obs["vector"]``.

    Args:
        observation_space: the env's ``Dict`` with ``"vector"`` and ``"belief_map"``.
        map_features: width of the map encoder's output.
        channels: output channels of the three convolutions.
    """

    def __init__(self, observation_space: spaces.Dict, map_features: int = 128,
                 channels: tuple[int, int, int] = (16, 32, 32)) -> None:
        if not isinstance(observation_space, spaces.Dict) or set(observation_space.spaces) != {
                MAP_KEY, VECTOR_KEY}:
            raise ValueError(f"BeliefMapExtractor needs a Dict observation with keys "
                             f"{VECTOR_KEY!r} and {MAP_KEY!r}, got {observation_space!r}")
        shape = observation_space[MAP_KEY].shape
        if len(shape) != 3 or min(shape[1:]) < 8:
            raise ValueError(f"belief_map must be (C, H, W) with H, W >= 8, got {shape}")
        if isinstance(map_features, bool) or not isinstance(map_features, int) or \
                map_features < 1:
            raise ValueError(f"map_features must be a positive integer, got {map_features!r}")
        n_vector = int(observation_space[VECTOR_KEY].shape[0])
        super().__init__(observation_space, features_dim=map_features + n_vector)
        layers: list[nn.Module] = []
        width = shape[0]
        for out in channels:
            layers += [nn.Conv2d(width, out, 3, stride=2, padding=1), nn.ReLU()]
            width = out
        self.cnn = nn.Sequential(*layers, nn.Flatten())
        with torch.no_grad():
            n_flat = int(self.cnn(torch.zeros((1, *shape))).shape[1])
        self.head = nn.Sequential(nn.Linear(n_flat, map_features), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        """Features ``(batch, map_features + len(vector))``."""
        belief = torch.sqrt(torch.clamp(observations[MAP_KEY], min=0.0))
        return torch.cat([self.head(self.cnn(belief)), observations[VECTOR_KEY]], dim=1)
