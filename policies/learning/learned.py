"""A trained stable-baselines3 model as a :class:`~policies.scripted.baselines.Policy`.

:class:`LearnedPolicy` wraps a model already in memory (the periodic
evaluation during training uses it); :class:`SB3Policy` loads a saved ``.zip``
(the algorithm detected from the file). One network acts for every live agent
(parameter sharing), deterministically, one batched forward pass per step.
Saved models of either backend load through
:func:`policies.learning.loader.load_learned_policy`.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from coop_loc_env.threads import set_torch_threads
from policies.learning.inference import INFERENCE_THREADS, check_observation_shape


class LearnedPolicy:
    """An SB3 model (in memory) shared by all agents.

    Args:
        model: a stable-baselines3 algorithm instance (``PPO``, ``SAC``, ...).
        name: label used in tables and plots.
        deterministic: use the mean action (``True`` for evaluation).
        threads: torch's (process-wide) intra-op thread count, set here (the
            ``COOP_LOC_TORCH_THREADS`` environment variable overrides it, see
            :mod:`coop_loc_env.threads`); ``None`` leaves it as it is.
    """

    def __init__(self, model: Any, name: str = "learned", deterministic: bool = True,
                 threads: int | None = INFERENCE_THREADS) -> None:
        if not hasattr(model, "predict") or not hasattr(model, "observation_space"):
            raise ValueError(f"model must be a stable-baselines3 model, got {type(model)!r}")
        if threads is not None:
            set_torch_threads(threads)
        self.model = model
        self.name = name
        #: the observation settings the network was trained with (config overrides an
        #: evaluation env needs; saved with the model by :mod:`policies.learning.training`)
        self.env_settings: dict[str, Any] = dict(getattr(model, "env_settings", None) or {})
        self.deterministic = deterministic
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env``; the observation shape must match the model's."""
        check_observation_shape(self.name, self.model.observation_space, env)
        self.env = env

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent (clipped to ``[-1, 1]``)."""
        agents = list(self.env.agents)
        if not agents:
            return {}
        first = obs[agents[0]]
        if isinstance(first, dict):  # obs_format="dict": one batch per key
            batch = {k: np.stack([obs[a][k] for a in agents]) for k in first}
        else:
            batch = np.stack([obs[a] for a in agents])
        actions, _ = self.model.predict(batch, deterministic=self.deterministic)
        actions = np.clip(np.asarray(actions, dtype=np.float32).reshape(len(agents), -1), -1, 1)
        return dict(zip(agents, actions, strict=True))


class SB3Policy(LearnedPolicy):
    """A saved stable-baselines3 model shared by every agent (parameter sharing).

    Args:
        path: the ``.zip`` written by ``model.save``.
        algo: ``"PPO"``, ``"SAC"``, ``"TD3"`` or ``"A2C"``; detected from the
            file when ``None``.
    """

    def __init__(self, path: str | Path, algo: str | None = None) -> None:
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"policy file {str(path)!r} does not exist")
        import stable_baselines3 as sb3

        algo = (algo or detect_sb3_algo(path)).upper()
        if not hasattr(sb3, algo):
            raise ValueError(f"unknown stable-baselines3 algorithm {algo!r} for {str(path)!r}")
        self.algo = algo
        super().__init__(getattr(sb3, algo).load(str(path), device="cpu"), name=path.stem)


def detect_sb3_algo(path: str | Path) -> str:
    """The algorithm a stable-baselines3 ``.zip`` was saved from (``"PPO"`` when unsure)."""
    try:
        with zipfile.ZipFile(path) as zf:
            data = zf.read("data").decode("utf-8", errors="replace")
    except (zipfile.BadZipFile, KeyError, OSError) as err:
        raise ValueError(f"{str(path)!r} is not a stable-baselines3 model zip: {err}") from err
    for algo in ("sac", "td3", "a2c", "ppo"):
        if f"stable_baselines3.{algo}." in data:
            return algo.upper()
    return "PPO"
