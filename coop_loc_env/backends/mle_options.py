"""The ``extras`` options of the pose-graph MLE backend (:mod:`coop_loc_env.backends.mle`)."""

from __future__ import annotations

from typing import Any

from coop_loc_env.extras import BackendOptions, flag, is_int, is_number, option

MLE_OPTIONS = BackendOptions({
    "mle_relative_slots": option(lambda v: is_int(v) and v >= 0, "an integer >= 0"),
    "mle_window": option(lambda v: is_int(v) and v >= 1, "an integer >= 1 or None",
                         none_ok=True),
    "mle_keyframe_interval": option(lambda v: is_number(v) and v >= 0,
                                    "a number >= 0 or None", none_ok=True),
    "mle_keep_history": flag(),
})


def check_extra(key: str, value: Any) -> None:
    """Raise ``ValueError`` naming ``key`` if ``value`` is not valid for this MLE option."""
    MLE_OPTIONS.check(key, value)
