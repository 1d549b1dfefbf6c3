"""Checks of the actions an env is given (one per agent, two real numbers in [-1, 1])."""

from __future__ import annotations

from typing import Any

import numpy as np

ACTION_TOLERANCE = 1e-6
"""How far outside [-1, 1] an action entry may lie (it is then clipped to the box)."""


def check_action(agent: str, action: Any) -> None:
    """Raise a ``ValueError`` naming ``agent`` if ``action`` is malformed.

    An action is a numpy array of integers or floats, or a list or tuple of
    two Python or numpy numbers; strings, booleans and complex numbers are refused.
    """
    if isinstance(action, np.ndarray):
        if action.dtype.kind not in "fiu":
            raise ValueError(
                f"action of {agent!r} must hold real numbers, got dtype {action.dtype}: "
                f"{action!r}"
            )
    elif isinstance(action, (list, tuple)):
        for x in action:
            if isinstance(x, (bool, np.bool_)) or not isinstance(
                x, (int, float, np.integer, np.floating)
            ):
                raise ValueError(
                    f"action of {agent!r} must hold two real numbers, got {x!r} in {action!r}"
                )
    elif isinstance(action, (bool, np.bool_)) or not isinstance(
        action, (int, float, np.number)
    ):
        raise ValueError(
            f"action of {agent!r} is not numeric (an array or a list of two numbers): "
            f"{type(action).__name__} {action!r}"
        )
    try:
        a = np.asarray(action, dtype=float)
    except (TypeError, ValueError) as err:
        raise ValueError(f"action of {agent!r} is not numeric: {action!r}") from err
    if a.shape != (2,):
        raise ValueError(
            f"action of {agent!r} must have shape (2,), got shape {a.shape}: {action!r}"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError(f"action of {agent!r} contains NaN or inf: {action!r}")
    if np.any(np.abs(a) > 1.0 + ACTION_TOLERANCE):
        raise ValueError(f"action of {agent!r} is outside [-1, 1]: {action!r}")
