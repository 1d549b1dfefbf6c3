"""The one way from a spec to a policy object: a registered name or a saved model.

* :func:`make_policy` resolves ``NAME`` / ``NAME:ARG`` against the registry of
  scripted policies (:mod:`policies.scripted.registry`), else loads the path as a
  saved model; ``scripts/evaluate.py``, ``--compare``, ``scripts/train.py``'s
  ``--eval-baseline`` and ``--bc-from`` all go through it.
* :func:`load_learned_policy` loads any saved policy: a stable-baselines3
  ``.zip`` (:class:`~policies.learning.learned.SB3Policy`), a training ``DIR``
  holding ``final_model.zip``, or an RLlib run ``DIR`` / checkpoint
  (:class:`~policies.learning.rllib_backend.RLlibPolicy`). Every policy it returns
  has the same ``reset(env, seed)`` / ``act(obs)`` interface.
"""

from __future__ import annotations

from pathlib import Path

from policies.learning.inference import is_rllib_run
from policies.learning.learned import SB3Policy
from policies.scripted.baselines import Policy
from policies.scripted.registry import policy_names, registered_policy


def make_policy(spec: str) -> Policy:
    """A policy from a registered name (``NAME`` or ``NAME:ARG``, see
    :func:`~policies.scripted.registry.policy_names`), the path of a saved
    stable-baselines3 model (``.zip``) or a training directory (SB3 or RLlib,
    :func:`load_learned_policy`)."""
    policy = registered_policy(spec)
    if policy is not None:
        return policy
    if str(spec).endswith(".zip") or Path(spec).is_file() or Path(spec).is_dir():
        return load_learned_policy(spec)
    raise ValueError(
        f"unknown policy {spec!r}: use one of {policy_names()}, the path of a saved "
        f"stable-baselines3 model (.zip) or a training directory"
    )


def load_learned_policy(path: str | Path):
    """Load a trained policy: a saved SB3 model (``.zip``, or a training ``DIR`` holding
    ``final_model.zip``) or an RLlib run ``DIR`` / checkpoint
    (:class:`policies.learning.rllib_backend.RLlibPolicy`, needs the ``rllib`` extra)."""
    path = Path(path)
    if is_rllib_run(path):
        try:
            from policies.learning.rllib_backend import RLlibPolicy
        except ImportError as err:
            raise ValueError(
                f"{str(path)!r} is an RLlib checkpoint: install the rllib extra "
                f"(pip install -e \".[rllib]\") to load it ({err})"
            ) from err
        return RLlibPolicy(path)
    if path.is_dir():
        path = path / "final_model.zip"
        if not path.is_file():
            raise ValueError(f"no saved model at {str(path)!r}")
    return SB3Policy(path)
