"""Training plumbing: vectorized envs, SB3 and RLlib training, behaviour cloning, saved policies.

* :mod:`policies.learning.vec_env` / :mod:`~policies.learning.sb3_vec_env` /
  :mod:`~policies.learning.env_copies`: the SB3 ``VecEnv`` over ParallelEnv copies,
  the env factory and the time-to-localize reward.
* :mod:`policies.learning.training`: ``TrainConfig``, ``train(cfg)`` (stable-baselines3).
* :mod:`policies.learning.rllib_backend`: RLlib PPO (the ``rllib`` extra).
* :mod:`policies.learning.imitation`: behaviour cloning of a scripted teacher.
* :mod:`policies.learning.loader`: ``make_policy(spec)`` (a registered name or a saved
  model) and ``load_learned_policy(path)`` (any saved SB3 or RLlib policy).

Imports :mod:`policies.scripted` (teachers, baselines), never :mod:`policies.experiments`.
"""
