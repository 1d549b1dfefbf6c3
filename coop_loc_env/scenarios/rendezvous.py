"""Rendezvous: half the team has no GPS, so where the robots drive decides how well they localize.

``outdoor_terrain`` with the team pattern ``(GPS, no GPS)`` cycled over four
robots started anywhere on the 40 m x 40 m field (``start_region=None``) with
a poor prior (``init_pos_std = 2 m``). A robot without GPS gets absolute
information only from relative updates with a teammate in its robot detector's
8 m range, and the starts are spread over the field, so a team that stays
apart dead-reckons while a team that gathers near its GPS-equipped members
localizes every robot. There are no steep patches (nothing to tip over).

The scenario also carries the training defaults of ``scripts/train.py
--scenario rendezvous`` (:data:`TRAINING_DEFAULTS`, read through
:func:`coop_loc_env.scenarios.training_defaults`).
"""

from __future__ import annotations

from coop_loc_env.config import RobotSpec
from coop_loc_env.scenarios import register_scenario, register_training_defaults
from coop_loc_env.scenarios.outdoor import outdoor_terrain

#: ``scripts/train.py`` option defaults for this scenario (option name -> value).
TRAINING_DEFAULTS: dict = {}


def rendezvous():
    """Four robots, every second one without GPS, started anywhere on the field."""
    return outdoor_terrain().replace(
        name="rendezvous",
        team=(RobotSpec(), RobotSpec(has_gps=False)),
        n_robots=4,
        start_region=None,
        init_pos_std=2.0,
        steep_patches=0,
        max_cycles=400,
    )


def _factory(overrides: dict):
    return rendezvous().replace(**overrides)


_factory.__doc__ = rendezvous.__doc__
register_scenario("rendezvous", _factory)
register_training_defaults("rendezvous", TRAINING_DEFAULTS)
