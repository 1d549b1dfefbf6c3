"""The ``extras`` options of the MCL backend (:mod:`coop_loc_env.backends.mcl`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from coop_loc_env.extras import BackendOptions, flag, is_int, is_number, option
from estimators.mcl.config import MCLConfig

#: MCLConfig fields a scenario may set through ``extras["mcl"]`` / ``["mcl_laser"]`` /
#: ``["mcl_sonar"]`` (the particle counts come from the config key ``n_particles``).
MCL_TUNABLE = frozenset(MCLConfig.__dataclass_fields__) - {"n_particles", "n_max"}


def _mcl_fields(key: str, value: Any) -> None:
    if not isinstance(value, dict):
        raise ValueError(f"extras[{key!r}] must be a dict of MCLConfig fields, got {value!r}")
    bad = sorted(set(value) - MCL_TUNABLE)
    if bad:
        raise ValueError(
            f"extras[{key!r}] has unknown MCLConfig field(s) {bad} (n_particles comes from "
            f"the config key n_particles); known: {sorted(MCL_TUNABLE)}"
        )


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


MCL_OPTIONS = BackendOptions(
    {
        "mcl": _mcl_fields,
        "mcl_laser": _mcl_fields,
        "mcl_sonar": _mcl_fields,
        "mcl_resolution": option(lambda v: is_number(v) and v > 0, "a positive number",
                                 none_ok=True),
        "mcl_laser_model": option(lambda v: v in ("likelihood_field", "beam"),
                                  "'likelihood_field' or 'beam'"),
        "mcl_detection_reset": option(lambda v: is_number(v) and 0.0 <= v < 1.0, "in [0, 1)"),
        "mcl_detection_exponent": option(lambda v: is_number(v) and 0.0 < v <= 1.0,
                                         "in (0, 1]"),
        "mcl_detection_check": flag(),
        "mcl_symmetry_check": flag(),
        "mcl_calibrated_copies": flag(),
        "mcl_global_init_factor": option(lambda v: is_int(v) and v >= 1, "an int >= 1"),
        "mcl_random_every_step": flag(),
    },
    check_config=lambda cfg: validate_mcl_values(cfg.extras, cfg.n_particles),
)


def check_extra(key: str, value: Any) -> None:
    """Raise ``ValueError`` naming ``key`` if ``value`` is not valid for this MCL option."""
    MCL_OPTIONS.check(key, value)
