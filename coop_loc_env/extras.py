"""The checks of :attr:`ScenarioConfig.extras <coop_loc_env.config.ScenarioConfig.extras>`.

``extras`` carries estimator options that only one backend reads. Each backend
declares its own keys in a :class:`BackendOptions` (the MCL backend's ``mcl_*``
in :mod:`coop_loc_env.backends.mcl_options`, the MLE backend's ``mle_*`` in
:mod:`coop_loc_env.backends.mle_options`, a user's backend as its ``options`` class
attribute or through ``register_backend(..., options=...)``); the registry
(:mod:`coop_loc_env.backends`) checks ``extras`` against every registered
backend's options, so that a misspelt key or a value out of range is a
``ValueError`` naming the key, like any other config field.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

#: ``check(key, value)``: raises ``ValueError`` naming ``key`` on a bad ``value``.
OptionCheck = Callable[[str, Any], None]


def is_number(value: Any) -> bool:
    """A finite int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
        value)


def is_int(value: Any) -> bool:
    """An int (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool)


def option(ok: Callable[[Any], bool], wanted: str, none_ok: bool = False) -> OptionCheck:
    """A check accepting the values ``ok`` accepts (and ``None`` with ``none_ok``);
    ``wanted`` words the error: ``extras['key'] must be <wanted>, got <value>``."""
    def check(key: str, value: Any) -> None:
        if (value is None and none_ok) or (value is not None and ok(value)):
            return
        raise ValueError(f"extras[{key!r}] must be {wanted}, got {value!r}")
    return check


def flag() -> OptionCheck:
    """A check accepting ``True`` or ``False``."""
    return option(lambda v: isinstance(v, bool), "True or False")


@dataclass(frozen=True)
class BackendOptions:
    """The ``extras`` keys one backend reads, each with its check.

    ``check_config(cfg)`` (optional) checks the values together with the rest of
    the config (e.g. building the filter configuration they feed).
    """

    checks: Mapping[str, OptionCheck] = field(default_factory=dict)
    check_config: Callable[[Any], None] | None = None

    def check(self, key: str, value: Any) -> None:
        """Raise ``ValueError`` naming ``key`` if ``value`` is not valid for it."""
        self.checks[key](key, value)


#: The options of a backend that reads no ``extras``.
NO_OPTIONS = BackendOptions()
