"""ScenarioConfig.extras: every key is declared and checked like any other field."""

from __future__ import annotations

import pytest

import coop_loc_env
from coop_loc_env.backends import extras_schema
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.profiles import PAPER_OVERRIDES, with_profile


def test_misspelt_extras_key_is_rejected_by_name():
    with pytest.raises(ValueError, match="'mcl_resolutoin'"):
        ScenarioConfig(extras={"mcl_resolutoin": 0.2, "mcl_detection_reset": 5.0}).validate()


@pytest.mark.parametrize(
    "extras, match",
    [
        ({"mcl_resolution": 0.2, "mcl_detection_reset": 5.0}, "mcl_detection_reset.*5.0"),
        ({"mcl_resolution": 0.0}, "mcl_resolution"),
        ({"mcl_random_every_step": "yes"}, "mcl_random_every_step"),
        ({"mcl": {"lf_sigma": -1.0}}, r"extras\['mcl'\].*lf_sigma"),
        ({"mcl_sonar": {"beam_sigma": 0.0}}, r"extras\['mcl_sonar'\].*beam_sigma"),
        ({"mle_window": 0}, "mle_window"),
        ({"mle_keyframe_interval": -1.0}, "mle_keyframe_interval"),
        ({"mle_keep_history": 1}, "mle_keep_history"),
    ],
)
def test_out_of_range_extras_value_is_rejected_by_name(extras, match):
    with pytest.raises(ValueError, match=match):
        ScenarioConfig(extras=extras).validate()
    with pytest.raises(ValueError, match=match):  # overrides are checked on construction
        coop_loc_env.make_config("outdoor_terrain", extras=extras)


def test_every_shipped_scenario_and_profile_uses_declared_extras_only():
    EXTRAS_SCHEMA = extras_schema()  # every registered backend's declared keys
    for name in coop_loc_env.list_scenarios():
        cfg = coop_loc_env.make_config(name)
        assert set(cfg.extras) <= set(EXTRAS_SCHEMA)
    for name in PAPER_OVERRIDES:
        coop_loc_env.make_config(name, **with_profile(name, "paper"))
    ScenarioConfig(extras={"mcl_resolution": None, "mle_window": None}).validate()


@pytest.mark.parametrize(
    "key, value",
    [("dt", 0.0), ("slip_std", -0.1), ("detection_prob", 1.5), ("ekf_process_noise_scale", 0.0),
     ("reward_uncertainty_weight", float("nan"))],
)
def test_field_bounds_declared_beside_the_fields_are_checked(key, value):
    with pytest.raises(ValueError, match=f"{key} must be"):
        ScenarioConfig().replace(**{key: value})


@pytest.mark.parametrize("key", ["cooperative_updates", "privileged_obs", "tip_over_terminates",
                                 "global_localization"])
def test_every_flag_refuses_a_string(key):
    """``--set cooperative_updates=false`` arrives as the string ``"false"``, which is truthy:
    every ``bool`` field refuses anything but True or False, naming the field and value."""
    with pytest.raises(ValueError, match=f"{key} must be True or False, got 'false'"):
        coop_loc_env.make_config("active_hallway", **{key: "false"})
    assert getattr(coop_loc_env.make_config("active_hallway", **{key: False}), key) is False
