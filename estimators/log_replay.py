"""Replay of logged multi-robot data: the public names of :mod:`estimators.replay`,
importable as ``estimators.log_replay`` too (see that package for the protocol)."""

from estimators.replay import *  # noqa: F403 (the package's public names, re-exported)
from estimators.replay import __all__  # noqa: F401
