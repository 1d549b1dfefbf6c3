"""Policies for coop-loc-env, by job.

* :mod:`policies.scripted` - the scripted controllers: Madhavan et al.'s
  traversal state machine (:class:`~policies.scripted.fsm.FSMPolicy`), the
  baselines (:mod:`~policies.scripted.baselines`), Fox et al.'s wander, Howard
  et al.'s dispersal and circuit, the active-localization policies, and the
  registry of policy names (:mod:`~policies.scripted.registry`).
* :mod:`policies.learning` - training plumbing and saved policies:
  :func:`~policies.learning.loader.make_policy` (a registered name or a saved
  SB3/RLlib model) and :func:`~policies.learning.loader.load_learned_policy`.
* :mod:`policies.experiments` - runs: the papers' experiments,
  :func:`~policies.experiments.runner.run_episodes`,
  :func:`~policies.experiments.report.summarize`, comparisons and plots.
* :mod:`policies.episode` - the episode loop all of them share.

Imports flow one way: experiments -> learning -> scripted (``policies.episode``
below all three).
"""

from policies.scripted.baselines import Policy, RandomPolicy, SeekTeammatePolicy
from policies.scripted.fsm import FSMParams, FSMPolicy, State, TraversalFSM

__all__ = [
    "FSMParams",
    "FSMPolicy",
    "Policy",
    "RandomPolicy",
    "SeekTeammatePolicy",
    "State",
    "TraversalFSM",
]
