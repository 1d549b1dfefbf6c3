"""The declared keys of :attr:`ScenarioConfig.extras <coop_loc_env.config.ScenarioConfig.extras>`.

``extras`` carries estimator options that only one backend reads (``mcl_*`` for
:mod:`coop_loc_env.mcl_backend`, ``mle_*`` for :mod:`coop_loc_env.mle_backend`).
Every key a backend reads is declared in :data:`EXTRAS_SCHEMA` with its check, so
that :meth:`ScenarioConfig.validate` rejects a misspelt key or a value out of range
with a ``ValueError`` naming the key, like any other config field. To add an
option: declare it here, then read it in the backend with ``cfg.extras.get``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from estimators.mcl.filter import MCLConfig

#: MCLConfig fields a scenario may set through ``extras["mcl"]`` / ``["mcl_laser"]`` /
#: ``["mcl_sonar"]`` (the particle counts come from the config key ``n_particles``).
MCL_TUNABLE = frozenset(MCLConfig.__dataclass_fields__) - {"n_particles", "n_max"}


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
        value)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _check(ok: Callable[[Any], bool], wanted: str, none_ok: bool = False
           ) -> Callable[[str, Any], None]:
    def check(key: str, value: Any) -> None:
        if (value is None and none_ok) or (value is not None and ok(value)):
            return
        raise ValueError(f"extras[{key!r}] must be {wanted}, got {value!r}")
    return check


def _mcl_fields(key: str, value: Any) -> None:
    if not isinstance(value, dict):
        raise ValueError(f"extras[{key!r}] must be a dict of MCLConfig fields, got {value!r}")
    bad = sorted(set(value) - MCL_TUNABLE)
    if bad:
        raise ValueError(
            f"extras[{key!r}] has unknown MCLConfig field(s) {bad} (n_particles comes from "
            f"the config key n_particles); known: {sorted(MCL_TUNABLE)}"
        )


#: Every key ``extras`` may hold, mapped to its check ``check(key, value)``.
EXTRAS_SCHEMA: dict[str, Callable[[str, Any], None]] = {
    # --- MCL (coop_loc_env.mcl_backend)
    "mcl": _mcl_fields,
    "mcl_laser": _mcl_fields,
    "mcl_sonar": _mcl_fields,
    "mcl_resolution": _check(lambda v: _is_number(v) and v > 0, "a positive number",
                             none_ok=True),
    "mcl_laser_model": _check(lambda v: v in ("likelihood_field", "beam"),
                              "'likelihood_field' or 'beam'"),
    "mcl_detection_reset": _check(lambda v: _is_number(v) and 0.0 <= v < 1.0, "in [0, 1)"),
    "mcl_detection_exponent": _check(lambda v: _is_number(v) and 0.0 < v <= 1.0, "in (0, 1]"),
    "mcl_detection_check": _check(lambda v: isinstance(v, bool), "True or False"),
    "mcl_global_init_factor": _check(lambda v: _is_int(v) and v >= 1, "an int >= 1"),
    "mcl_random_every_step": _check(lambda v: isinstance(v, bool), "True or False"),
    # --- pose-graph MLE (coop_loc_env.mle_backend)
    "mle_relative_slots": _check(lambda v: _is_int(v) and v >= 0, "an integer >= 0"),
    "mle_window": _check(lambda v: _is_int(v) and v >= 1, "an integer >= 1 or None",
                         none_ok=True),
    "mle_keyframe_interval": _check(lambda v: _is_number(v) and v >= 0,
                                    "a number >= 0 or None", none_ok=True),
    "mle_keep_history": _check(lambda v: isinstance(v, bool), "True or False"),
}


def check_extra(key: str, value: Any) -> None:
    """Raise ``ValueError`` naming ``key`` if ``value`` is not valid for it."""
    EXTRAS_SCHEMA[key](key, value)


def validate_extras(extras: Mapping[str, Any]) -> None:
    """Raise ``ValueError`` naming the key on an undeclared key or a bad value."""
    if not isinstance(extras, Mapping):
        raise ValueError(f"extras must be a dict, got {extras!r}")
    for key, value in extras.items():
        if key not in EXTRAS_SCHEMA:
            raise ValueError(
                f"unknown extras key {key!r}; known keys: {', '.join(sorted(EXTRAS_SCHEMA))}"
            )
        check_extra(key, value)


def validate_mcl_values(extras: Mapping[str, Any], n_particles: int) -> None:
    """Build the MCLConfig each sensor type's filter gets from ``extras`` (as the MCL
    backend does) and raise ``ValueError`` naming the extras key on a bad value."""
    base = extras.get("mcl", {})
    for key, tuned in (("mcl", {}), ("mcl_laser", extras.get("mcl_laser", {})),
                       ("mcl_sonar", extras.get("mcl_sonar", {}))):
        fields = {"n_particles": n_particles, "n_max": n_particles, "n_min": 100,
                  **base, **tuned}
        fields["n_min"] = min(n_particles, fields["n_min"])
        try:
            MCLConfig(**fields)
        except (ValueError, TypeError) as err:
            raise ValueError(f"extras[{key!r}] has a bad value: {err}") from err
