"""Runs of policies on scenarios: the papers' experiments, evaluation, comparison, plots.

* :mod:`policies.experiments.fox`, :mod:`~policies.experiments.howard`,
  :mod:`~policies.experiments.madhavan`: the experiments of Fox et al., Howard et
  al. and Madhavan et al. behind ``scripts/reproduce_*.py``.
* :mod:`policies.experiments.runner` (episodes of a policy, frames for a GIF) and
  :mod:`~policies.experiments.report` (summary, JSON, table): ``scripts/evaluate.py``.
* :mod:`policies.experiments.compare`: policies side by side with 95 % intervals.
* :mod:`policies.experiments.plots`: error and terrain figures.

Imports :mod:`policies.scripted` and :mod:`policies.learning`; neither imports this.
"""
