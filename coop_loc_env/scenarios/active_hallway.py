"""Active hallway: sonar robots localize globally in a symmetric ring; how they drive decides when.

``symmetric_hallway`` (Fox et al.'s Fig. 12 world) with four robots, up to
1000 particles each and a 120 s horizon. The ring of corridors is symmetric
under quarter turns; only the open bay off the left corridor breaks the
symmetry, so a robot knows where it is only after its sonar has seen the bay,
or after a detection by a teammate that has. A robot that stands still
localizes only if it starts in sight of the bay (or is detected by one that
does), one that wanders slowly takes longer, and one that drives the
corridors at full speed without stalling against the walls sees the bay
sooner and meets its teammates more often.

The figure of merit is the time to localize (:mod:`policies.experiments.compare`: the first
time a robot's particle spread -- the mean particle distance from the true
pose -- falls below 1.5 m, the episode length for a robot that never gets
there). For learning, the scenario carries the training defaults of
``scripts/train.py --scenario active_hallway`` (:data:`TRAINING_DEFAULTS`):
the dict observation (``obs_format="dict"``: the belief map and its modes) and,
as reward, minus the time to localize
(:class:`policies.learning.vec_env.TimeToLocalizeReward`), paid per robot.
"""

from __future__ import annotations

from coop_loc_env.scenarios import (
    CLONE_THEN_PPO,
    register_scenario,
    register_training_defaults,
    scenario_from_base,
)
from coop_loc_env.scenarios.fox import symmetric_hallway

#: ``scripts/train.py`` option defaults for this scenario (option dest -> value): the
#: dict observation (the belief map, read by a small CNN), the cloning recipe of
#: ``CLONE_THEN_PPO`` with the ``corridor`` teacher on fewer episodes (a CNN fits them
#: slower), on minus the time to localize (per robot, half its own, half the team's;
#: minus 0.1 per new contact).
TRAINING_DEFAULTS: dict = {
    **CLONE_THEN_PPO,
    "obs_format": "dict",
    "bc_episodes": 8,
    "bc_epochs": 20,
    "dagger_rounds": 3,
    "dagger_epochs": 8,
    "bc_from": "corridor",
    "reward_mode": "localize",
    "localize_step_reward": 0.1,
    "localize_team_weight": 0.5,
    "localize_collision_weight": 0.1,
    "eval_episodes": 4,
    "eval_baseline": "wander:1.0",
}


def active_hallway():
    """Four sonar robots (1000 particles each) localize globally in the symmetric hallway."""
    return symmetric_hallway().replace(
        name="active_hallway",
        n_robots=4,
        n_particles=1000,
        max_cycles=240,
    )


register_scenario("active_hallway", scenario_from_base(active_hallway))
register_training_defaults("active_hallway", TRAINING_DEFAULTS)
