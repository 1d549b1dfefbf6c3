"""Rendezvous: half the team has no GPS, so where the robots drive decides how well they localize.

``outdoor_terrain`` with the team pattern ``(GPS, no GPS)`` cycled over four
robots started anywhere on the 40 m x 40 m field (``start_region=None``) with
a poor prior (``init_pos_std = 2 m``). A robot without GPS gets absolute
information only from relative updates with a teammate in its robot detector's
8 m range, and the starts are spread over the field, so a team that stays
apart dead-reckons while a team that gathers near its GPS-equipped members
localizes every robot. There are no steep patches (nothing to tip over).

For learning, the observation carries the teammates block (``teammate_obs``:
bearing, distance and uncertainty of the nearest teammate with GPS and of the
nearest without, from the estimates the team shares) and the reward adds
``reward_team_weight = 0.5`` times minus the team's mean position error and
``reward_uncertainty_weight = 1`` times minus the change of the robot's own
``0.5 log det`` position covariance (``info["reward_<term>"]``).

The scenario also carries the training defaults of ``scripts/train.py
--scenario rendezvous`` (:data:`TRAINING_DEFAULTS`, read through
:func:`coop_loc_env.scenarios.training_defaults`).
"""

from __future__ import annotations

from coop_loc_env.config import RobotSpec
from coop_loc_env.scenarios import (
    CLONE_THEN_PPO,
    register_scenario,
    register_training_defaults,
    scenario_from_base,
)
from coop_loc_env.scenarios.outdoor import outdoor_terrain

#: ``scripts/train.py`` option defaults for this scenario (option dest -> value): clone
#: the ``gather`` baseline with DAgger, then fine-tune with a cautious PPO (small steps,
#: critic pre-fitted on the clone's returns, so no reward normalization), until the
#: wall-clock limit. Chosen by the ablations in docs/learning.md.
TRAINING_DEFAULTS: dict = {
    **CLONE_THEN_PPO,
    "bc_from": "gather",
    "eval_episodes": 3,
}


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
        # for learning: the teammates' shared estimates in the observation, and rewards
        # that pay a robot for its teammates' accuracy and for shrinking its own belief
        teammate_obs=True,
        reward_team_weight=0.5,
        reward_uncertainty_weight=1.0,
    )


register_scenario("rendezvous", scenario_from_base(rendezvous))
register_training_defaults("rendezvous", TRAINING_DEFAULTS)
