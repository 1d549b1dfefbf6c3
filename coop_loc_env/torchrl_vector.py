"""A batched native TorchRL environment: ``num_envs`` worlds with ``batch_size=[num_envs]``.

:class:`CoopLocTorchRLVectorEnv` is a ``torchrl.envs.EnvBase`` around
:class:`~coop_loc_env.vector.CoopLocVectorEnv` with the group layout of
:class:`~coop_loc_env.native_torchrl.CoopLocTorchRLEnv`, one batch dimension in front
(as TorchRL's ``VmasEnv``): group ``robot`` holding ``observation`` ``(B, n, obs_dim)``,
``action`` ``(B, n, 2)``, ``reward``, ``done``, ``terminated`` and ``truncated``
``(B, n, 1)``, ``mask`` ``(B, n)`` (the robot is still in its episode after this step)
and ``info`` (one ``(B, n)`` float entry per info key), plus each world's ``done``,
``terminated`` and ``truncated`` ``(B, 1)`` at the root. A world is done when every
robot of it is; TorchRL resets the done worlds (the ``_reset`` mask), each continuing
its own random stream. ``set_seed(s)`` seeds world ``i`` of the next full reset with
``s + i``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from coop_loc_env.native_torchrl import GROUP
from coop_loc_env.vector import CoopLocVectorEnv

#: The infos carried by default (cheap ones; ``info_keys=[...]`` adds the vector env's
#: opt-in keys, e.g. ``coverage``).
DEFAULT_INFO_KEYS = ("position_error", "heading_error", "collisions", "tipped_over")


class CoopLocTorchRLVectorEnv(EnvBase):
    """The worlds of ``env`` as one TorchRL batch (see the module docstring).

    Args:
        env: the batched env; built here with ``autoreset=False`` by
            :func:`make_torchrl_vector_env` (TorchRL resets the done worlds itself).
        device: the torch device of the tensors.
        seed: the seed of the first reset (world ``i`` gets ``seed + i``).
        info_name: the name of the info entry in the group.
    """

    def __init__(self, env: CoopLocVectorEnv, device: str | torch.device = "cpu",
                 seed: int | None = None, info_name: str = "info") -> None:
        space = env.single_observation_space
        if not isinstance(space, spaces.Box):
            raise ValueError(
                f"the TorchRL env needs Box observations, got {type(space).__name__}")
        if env.autoreset:
            raise ValueError("the TorchRL env resets done worlds itself: build the vector "
                             "env with autoreset=False")
        B, n = env.num_envs, env.n_robots
        super().__init__(device=device, batch_size=torch.Size([B]))
        self.env = env
        self.n_agents = n
        self.agents = list(env.possible_agents)
        self._obs_dim = int(np.prod(space.shape))
        self._seed = seed
        self.info_name = info_name
        env.reset(seed=seed)  # the info keys are checked at the first reset
        self._seed = seed
        self.info_keys = tuple(k for k in env.info_keys)
        dev = self.device
        group_shape = (B, n)
        info_spec = Composite(
            {k: Unbounded(shape=group_shape, dtype=torch.float32, device=dev)
             for k in self.info_keys},
            shape=group_shape, device=dev,
        )
        low = torch.tensor(np.broadcast_to(space.low, space.shape).reshape(-1))
        high = torch.tensor(np.broadcast_to(space.high, space.shape).reshape(-1))
        self.observation_spec = Composite(
            {GROUP: Composite(
                observation=Bounded(low.expand(B, n, -1), high.expand(B, n, -1),
                                    shape=(B, n, self._obs_dim), dtype=torch.float32,
                                    device=dev),
                mask=Categorical(2, shape=group_shape, dtype=torch.bool, device=dev),
                **{info_name: info_spec}, shape=group_shape, device=dev)},
            shape=(B,), device=dev,
        )
        self.action_spec = Composite(
            {GROUP: Composite(action=Bounded(-1.0, 1.0, shape=(B, n, 2), dtype=torch.float32,
                                             device=dev), shape=group_shape, device=dev)},
            shape=(B,), device=dev,
        )
        self.reward_spec = Composite(
            {GROUP: Composite(reward=Unbounded(shape=(B, n, 1), dtype=torch.float32,
                                               device=dev), shape=group_shape, device=dev)},
            shape=(B,), device=dev,
        )
        flag = {"shape": (B, n, 1), "dtype": torch.bool, "device": dev}
        team = {"shape": (B, 1), "dtype": torch.bool, "device": dev}
        self.done_spec = Composite(
            {
                GROUP: Composite(done=Categorical(2, **flag), terminated=Categorical(2, **flag),
                                 truncated=Categorical(2, **flag), shape=group_shape,
                                 device=dev),
                "done": Categorical(2, **team),
                "terminated": Categorical(2, **team),
                "truncated": Categorical(2, **team),
            },
            shape=(B,), device=dev,
        )

    # ------------------------------------------------------------------ EnvBase
    def _set_seed(self, seed: int | None) -> int | None:
        self._seed = seed  # the next full reset starts the seeded episodes
        return seed

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        worlds = None
        if tensordict is not None:
            mask = tensordict.get("_reset", None)
            if mask is None:
                mask = tensordict.get((GROUP, "_reset"), None)
            if mask is not None:
                worlds = mask.reshape(self.env.num_envs, -1).any(-1).cpu().numpy()
        if worlds is None or worlds.all():
            obs, _ = self.env.reset(seed=self._seed)
            self._seed = None  # later resets continue each world's stream
        else:
            obs, _ = self.env.reset(worlds=worlds)
        B, n = self.env.num_envs, self.n_agents
        false = torch.zeros((B, n, 1), dtype=torch.bool)
        nan = torch.full((B, n), float("nan"))
        group = TensorDict({
            "observation": torch.from_numpy(obs),
            "mask": torch.from_numpy(self.env.mask),
            self.info_name: TensorDict({k: nan.clone() for k in self.info_keys},
                                       batch_size=(B, n)),
            "done": false, "terminated": false.clone(), "truncated": false.clone(),
        }, batch_size=(B, n))
        team_false = torch.zeros((B, 1), dtype=torch.bool)
        out = TensorDict({GROUP: group, "done": team_false, "terminated": team_false.clone(),
                          "truncated": team_false.clone()}, batch_size=(B,))
        return out if self.device == torch.device("cpu") else out.to(self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        act = tensordict.get((GROUP, "action")).detach().cpu().numpy()
        obs, rewards, term, trunc, infos = self.env.step(act)
        B, n = self.env.num_envs, self.n_agents
        term_t = torch.from_numpy(term).unsqueeze(-1)
        trunc_t = torch.from_numpy(trunc).unsqueeze(-1)
        still_in = self.env.mask
        world_done = ~still_in.any(axis=1)
        world_term = world_done & term.all(axis=1)
        table = np.stack([infos[k] for k in self.info_keys]).astype(np.float32, copy=False)
        group = TensorDict({
            "observation": torch.from_numpy(obs),
            "reward": torch.from_numpy(rewards.astype(np.float32)).unsqueeze(-1),
            "mask": torch.from_numpy(still_in),
            self.info_name: TensorDict(
                dict(zip(self.info_keys, torch.from_numpy(table).unbind(0), strict=True)),
                batch_size=(B, n)),
            "done": term_t | trunc_t, "terminated": term_t, "truncated": trunc_t,
        }, batch_size=(B, n))
        out = TensorDict({
            GROUP: group,
            "done": torch.from_numpy(world_done).unsqueeze(-1),
            "terminated": torch.from_numpy(world_term).unsqueeze(-1),
            "truncated": torch.from_numpy(world_done & ~world_term).unsqueeze(-1),
        }, batch_size=(B,))
        return out if self.device == torch.device("cpu") else out.to(self.device)

    def close(self, *args: Any, **kwargs: Any) -> None:
        """Close the worlds (and TorchRL's side)."""
        self.env.close()
        super().close(*args, **kwargs)


def make_torchrl_vector_env(
    scenario: str, num_envs: int, seed: int | None = None, device: str | torch.device = "cpu",
    info_keys: list[str] | tuple[str, ...] | None = None, info_name: str = "info",
    **overrides: Any,
) -> CoopLocTorchRLVectorEnv:
    """The batched TorchRL env of ``scenario`` (any config field overridable by keyword)."""
    keys = DEFAULT_INFO_KEYS if info_keys is None else tuple(info_keys)
    env = CoopLocVectorEnv(scenario, num_envs=num_envs, info_keys=keys, autoreset=False,
                           **overrides)
    return CoopLocTorchRLVectorEnv(env, device=device, seed=seed, info_name=info_name)
