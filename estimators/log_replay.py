"""Replay of logged multi-robot data: the names of :mod:`estimators.replay`, importable
from their former module (see that package for the protocol)."""

from estimators.replay import *  # noqa: F403 (the package's public names, re-exported)
from estimators.replay import __all__  # noqa: F401
