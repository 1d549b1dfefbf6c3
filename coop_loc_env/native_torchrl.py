"""A native TorchRL environment: the team steps as one batch, ready for a collector.

:class:`CoopLocTorchRLEnv` is a ``torchrl.envs.EnvBase`` around
:class:`~coop_loc_env.env.CoopLocParallelEnv` with the layout of TorchRL's
``PettingZooWrapper(env, use_mask=True, done_on_any=False)``: one group,
``robot``, holding ``observation`` ``(n, obs_dim)``, ``action`` ``(n, 2)``,
``reward``, ``done``, ``terminated`` and ``truncated`` ``(n, 1)``, ``mask`` ``(n,)``
(the robot is still in the episode after this step) and ``info`` (one ``(n,)``
float entry per scalar info key), plus the team's ``done``, ``terminated`` and
``truncated`` at the root. The episode ends when every robot is done; a robot
that tipped over earlier gets zero observations and rewards, its actions are
ignored and its ``mask`` is False. Truncation (``max_cycles``) is kept apart from
termination, so that a trainer can bootstrap it.

It skips the wrapper's per-agent dict work (every agent, every key, each step),
which is most of what the wrapper costs (docs/scaling.md has the figures).
Needs ``torch`` and ``torchrl`` (``pip install -e ".[torchrl]"``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from coop_loc_env.env import CoopLocParallelEnv

#: The group every robot belongs to (the name TorchRL's PettingZooWrapper gives them).
GROUP = "robot"

#: The infos carried by default: the figures a trainer logs (each env also adds its
#: estimators' scalar entries, e.g. MCL's ``particle_spread``; NaN for robots without them).
DEFAULT_INFO_KEYS = (
    "position_error", "heading_error", "gps_fix", "collisions", "tipped_over", "coverage",
    "map_rmse",
)


class CoopLocTorchRLEnv(EnvBase):
    """The team of ``env`` as one TorchRL batch (see the module docstring for the layout).

    Args:
        env: the parallel environment (its observations must be a ``Box``).
        info_keys: the info keys to carry under ``(robot, info)`` (numbers only); by
            default :data:`DEFAULT_INFO_KEYS` and the estimators' own scalar entries.
        device: the torch device of the tensors.
        info_name: the name of the info entry in the group (BenchMARL's tasks use
            ``coop_info``, which they log NaN-aware themselves).
        seed: the seed of the first reset (later resets continue the env's generator;
            ``set_seed`` seeds the next one).
    """

    def __init__(
        self,
        env: CoopLocParallelEnv,
        info_keys: list[str] | tuple[str, ...] | None = None,
        device: str | torch.device = "cpu",
        seed: int | None = None,
        info_name: str = "info",
    ) -> None:
        space = env.observation_space(env.possible_agents[0])
        if not isinstance(space, spaces.Box):
            raise ValueError(
                f"the TorchRL env needs Box observations, got {type(space).__name__}"
            )
        super().__init__(device=device, batch_size=torch.Size([]))
        self.env = env
        self.agents = list(env.possible_agents)
        self.n_agents = n = len(self.agents)
        self._obs_dim = int(np.prod(space.shape))
        _, infos = env.reset(seed=seed)  # to read the info keys; the first _reset() repeats it
        self._seed = seed
        first = infos[self.agents[0]]
        if info_keys is None:
            extra = [key for b in env.backends for entries in b.extra_info(env.world.poses)
                     .values() for key in entries if np.ndim(first.get(key)) == 0]
            info_keys = list(dict.fromkeys([*DEFAULT_INFO_KEYS, *extra]))
        for key in info_keys:
            if key not in first or np.ndim(first[key]) != 0:
                scalars = [k for k, v in first.items() if np.ndim(v) == 0]
                raise ValueError(
                    f"info_keys names {key!r}, not a scalar info key of this env; "
                    f"its scalar keys: {', '.join(scalars)}"
                )
        self.info_keys = tuple(info_keys)
        self.info_name = info_name
        dev = self.device
        info_spec = Composite(
            {k: Unbounded(shape=(n,), dtype=torch.float32, device=dev) for k in self.info_keys},
            shape=(n,), device=dev,
        )
        low = torch.tensor(np.broadcast_to(space.low, space.shape).reshape(-1))
        high = torch.tensor(np.broadcast_to(space.high, space.shape).reshape(-1))
        obs = (
            Bounded(low.expand(n, -1), high.expand(n, -1), shape=(n, self._obs_dim),
                    dtype=torch.float32, device=dev)
            if bool(torch.isfinite(low).all() and torch.isfinite(high).all())
            else Unbounded(shape=(n, self._obs_dim), dtype=torch.float32, device=dev)
        )
        self.observation_spec = Composite(
            {GROUP: Composite(
                observation=obs,
                mask=Categorical(2, shape=(n,), dtype=torch.bool, device=dev),
                **{info_name: info_spec}, shape=(n,), device=dev)},
            device=dev,
        )
        self.action_spec = Composite(
            {GROUP: Composite(action=Bounded(-1.0, 1.0, shape=(n, 2), dtype=torch.float32,
                                             device=dev), shape=(n,), device=dev)},
            device=dev,
        )
        self.reward_spec = Composite(
            {GROUP: Composite(reward=Unbounded(shape=(n, 1), dtype=torch.float32, device=dev),
                              shape=(n,), device=dev)},
            device=dev,
        )
        flag = {"shape": (n, 1), "dtype": torch.bool, "device": dev}
        team = {"shape": (1,), "dtype": torch.bool, "device": dev}
        self.done_spec = Composite(
            {
                GROUP: Composite(done=Categorical(2, **flag), terminated=Categorical(2, **flag),
                                 truncated=Categorical(2, **flag), shape=(n,), device=dev),
                "done": Categorical(2, **team),
                "terminated": Categorical(2, **team),
                "truncated": Categorical(2, **team),
            },
            device=dev,
        )
        self._terminated = np.zeros(n, dtype=bool)
        self._truncated = np.zeros(n, dtype=bool)
        self._index = {a: i for i, a in enumerate(self.agents)}

    # ------------------------------------------------------------------ EnvBase
    def _set_seed(self, seed: int | None) -> int | None:
        self._seed = seed  # the next reset starts the seeded episode
        return seed

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        obs_d, infos = self.env.reset(seed=self._seed)
        self._seed = None  # later resets continue the env's generator
        obs = self._stack_obs(obs_d)
        self._terminated[:] = False
        self._truncated[:] = False
        n = self.n_agents
        false = torch.zeros((n, 1), dtype=torch.bool, device=self.device)
        group = {
            "observation": torch.from_numpy(obs).to(self.device),
            "mask": torch.ones(n, dtype=torch.bool, device=self.device),
            self.info_name: self._info_td(infos, self.agents),
            "done": false,
            "terminated": false.clone(),
            "truncated": false.clone(),
        }
        team_false = torch.zeros(1, dtype=torch.bool, device=self.device)
        return TensorDict(
            {GROUP: TensorDict(group, batch_size=(n,), device=self.device),
             "done": team_false, "terminated": team_false.clone(),
             "truncated": team_false.clone()},
            batch_size=(), device=self.device,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        env = self.env
        act = tensordict.get((GROUP, "action")).detach().cpu().numpy()
        live = env.agents
        n = self.n_agents
        if len(live) == n:
            actions = dict(zip(live, act, strict=True))
        else:
            actions = {a: act[self._index[a]] for a in live}
        obs_d, rew_d, term_d, trunc_d, infos = env.step(actions)
        if len(live) == n:
            obs = np.stack(list(obs_d.values())).astype(np.float32, copy=False)
            reward = np.fromiter(rew_d.values(), dtype=np.float32, count=n)
            self._terminated[:] = list(term_d.values())
            self._truncated[:] = list(trunc_d.values())
        else:
            rows = [self._index[a] for a in live]
            obs = np.zeros((n, self._obs_dim), dtype=np.float32)
            reward = np.zeros(n, dtype=np.float32)
            if rows:
                obs[rows] = np.stack([obs_d[a] for a in live])
                reward[rows] = [rew_d[a] for a in live]
                self._terminated[rows] = [term_d[a] for a in live]
                self._truncated[rows] = [trunc_d[a] for a in live]
        still_in = np.zeros(n, dtype=bool)
        if env.agents:
            still_in[[self._index[a] for a in env.agents]] = True
        term = torch.from_numpy(self._terminated.copy()).unsqueeze(-1)
        trunc = torch.from_numpy(self._truncated.copy()).unsqueeze(-1)
        done = term | trunc
        all_done = not env.agents
        dev = self.device
        group = TensorDict(
            {
                "observation": torch.from_numpy(obs),
                "reward": torch.from_numpy(reward).unsqueeze(-1),
                "mask": torch.from_numpy(still_in),
                self.info_name: self._info_td(infos, live),
                "done": done,
                "terminated": term,
                "truncated": trunc,
            },
            batch_size=(n,),
        )
        team_term = bool(all_done and self._terminated.all())
        out = TensorDict(
            {
                GROUP: group,
                "done": torch.tensor([all_done]),
                "terminated": torch.tensor([team_term]),
                "truncated": torch.tensor([all_done and not team_term]),
            },
            batch_size=(),
        )
        return out if dev == torch.device("cpu") else out.to(dev)

    # ------------------------------------------------------------------ helpers
    def _stack_obs(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        out = np.zeros((self.n_agents, self._obs_dim), dtype=np.float32)
        for agent, value in obs.items():
            out[self._index[agent]] = np.asarray(value, dtype=np.float32).reshape(-1)
        return out

    def _info_td(self, infos: dict[str, dict], agents: list[str]) -> TensorDict:
        """``(n,)`` float32 per info key; NaN for robots without an info this step."""
        n, keys = self.n_agents, self.info_keys
        table = np.full((len(keys), n), np.nan, dtype=np.float32)
        if len(agents) == n:
            table[:] = [[info[k] for info in infos.values()] for k in keys]
        elif agents:
            idx = [self._index[a] for a in agents]
            table[:, idx] = [[infos[a][k] for a in agents] for k in keys]
        cols = torch.from_numpy(table).unbind(0)
        return TensorDict(dict(zip(keys, cols, strict=True)), batch_size=(n,),
                          device=self.device)

    def close(self, *args: Any, **kwargs: Any) -> None:
        """Close the parallel env (and TorchRL's side)."""
        self.env.close()
        super().close(*args, **kwargs)


def make_torchrl_env(
    scenario: str = "outdoor_terrain",
    seed: int | None = None,
    device: str | torch.device = "cpu",
    info_keys: list[str] | tuple[str, ...] | None = None,
    **overrides: Any,
) -> CoopLocTorchRLEnv:
    """The native TorchRL env of ``scenario`` (any config field overridable by keyword)."""
    return CoopLocTorchRLEnv(CoopLocParallelEnv(scenario=scenario, **overrides),
                             info_keys=info_keys, device=device, seed=seed)
