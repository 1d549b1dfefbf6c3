"""Outdoor scenarios after Madhavan, Fregene and Parker: robots among trees on hilly terrain."""

from __future__ import annotations

from coop_loc_env.config import ScenarioConfig
from coop_loc_env.scenarios import register_scenario, scenario_from_base


def outdoor_terrain() -> ScenarioConfig:
    """2-4 skid-steer robots (3 by default) on a 40 m x 40 m hilly field with trees.

    Tree canopies block DGPS satellites, rocks and trees are obstacles, five
    objects of interest are scattered for the camera, and two steep mounds can
    tip a robot over. Every robot carries the full sensor suite of the paper
    (odometry, DGPS, compass, inclinometer, laser, camera, robot detector).
    """
    return ScenarioConfig(
        name="outdoor_terrain",
        n_robots=3,
        world_size=(40.0, 40.0),
        layout_seed=7,
        n_random_trees=30,
        n_random_rocks=6,
        n_random_ooi=5,
        canopy_radius=3.0,
        start_region=(4.0, 4.0, 14.0, 14.0),
        terrain_amplitude=1.5,
        terrain_hills=10,
        steep_patches=2,
        max_cycles=500,
    )


register_scenario("outdoor_terrain", scenario_from_base(outdoor_terrain))
