"""The DGPS-outage experiment of Madhavan, Fregene and Parker (their Fig. 4(b)).

Two robots drive east side by side across a flat field. The northern lane
(robot 1) passes under the wide canopy of a single tree, where the satellites
in view drop below four and DGPS fixes stop (from about t = 21 s, as in the
paper); the southern lane (robot 0) stays in open sky. Every five seconds
(``detector_rate = 0.2`` Hz) one robot finds the other with its laser
(``detection_model = "laser"``: the minimum of its range profile) and the
robots run the cooperative joint update (Eq. 3, ``cooperative_fusion =
"naive"``, the paper's form). Robot 1's position standard deviation grows
during the outage and falls at each of these laser-based updates.

Odometry is sampled at 10 Hz with a larger velocity noise than the default so
that dead reckoning drifts visibly over the ~17 s outage; the robots are meant
to be driven straight east at ``0.5 m/s`` (see
:func:`policies.experiments.madhavan.run_dgps_outage`).
"""

from __future__ import annotations

from coop_loc_env.config import Obstacle, ScenarioConfig
from coop_loc_env.scenarios import register_scenario, scenario_from_base

#: The tree whose canopy covers robot 1's lane.
CANOPY_TREE = Obstacle("tree", "circle", center=(20.0, 15.0), radius=0.4, canopy_radius=8.0)
LANE_SPEED = 0.5  # m/s, the speed the experiment drives at


def dgps_outage() -> ScenarioConfig:
    """Two robots, one loses DGPS under a tree canopy; laser-based cooperative updates."""
    return ScenarioConfig(
        name="dgps_outage",
        n_robots=2,
        world_size=(40.0, 20.0),
        layout_seed=0,
        obstacles=(CANOPY_TREE,),
        n_random_trees=0,
        n_random_rocks=0,
        n_random_ooi=0,
        terrain_amplitude=0.3,
        terrain_hills=3,
        steep_patches=0,
        start_poses=((6.5, 8.0, 0.0), (6.5, 12.0, 0.0)),
        max_cycles=500,
        max_speed=1.0,
        odometry_rate=10.0,
        odom_v_std=0.5,
        odom_w_std=0.05,
        detection_model="laser",
        detector_rate=0.2,
        detector_range=8.0,
        false_positive_prob=0.0,
        detection_prob=1.0,
        cooperative_fusion="naive",
        gps_multipath_prob=0.0,
        init_pos_std=0.3,
    )


register_scenario("dgps_outage", scenario_from_base(dgps_outage))
