"""Policies for coop-loc-env: the terrain-traversal state machine, baselines, evaluation.

* :class:`~policies.fsm.FSMPolicy` - Madhavan et al.'s Fig. 7 traversal logic per robot.
* :class:`~policies.baselines.RandomPolicy`, :class:`~policies.baselines.SeekTeammatePolicy`.
* :mod:`policies.runner` - :func:`~policies.runner.make_policy` (names or a saved
  stable-baselines3 model), :func:`~policies.runner.run_episodes`,
  :func:`~policies.runner.summarize`.
"""

from policies.baselines import Policy, RandomPolicy, SeekTeammatePolicy
from policies.fsm import FSMParams, FSMPolicy, State, TraversalFSM

__all__ = [
    "FSMParams",
    "FSMPolicy",
    "Policy",
    "RandomPolicy",
    "SeekTeammatePolicy",
    "State",
    "TraversalFSM",
]
