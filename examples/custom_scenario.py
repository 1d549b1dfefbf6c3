"""Register a scenario of your own: a walled yard, a mixed team (EKF and MCL robots).

    python examples/custom_scenario.py

A scenario is a function returning a ScenarioConfig; every field can still be
overridden by keyword when the env is made. Fields and units:
coop_loc_env/config.py.
"""

from __future__ import annotations

import numpy as np

import coop_loc_env
from coop_loc_env import Obstacle, RobotSpec, ScenarioConfig
from coop_loc_env.scenarios import scenario_from_base


def walled_yard() -> ScenarioConfig:
    """Four robots in a flat 15 m x 15 m yard with a wall: two with GPS (EKF), two without (MCL)."""
    return ScenarioConfig(
        name="walled_yard",
        n_robots=4,
        team=(RobotSpec(estimator="ekf"), RobotSpec(estimator="mcl", has_gps=False)),
        world_size=(15.0, 15.0),
        obstacles=(Obstacle("wall", "segment", a=(5.0, 3.0), b=(5.0, 12.0), radius=0.1),),
        n_random_trees=6,
        terrain_amplitude=0.0,
        steep_patches=0,
        n_particles=300,
        max_cycles=50,
    )


def main() -> None:
    if "walled_yard" not in coop_loc_env.list_scenarios():
        coop_loc_env.register_scenario("walled_yard", scenario_from_base(walled_yard))
    print(coop_loc_env.describe_scenario("walled_yard"))
    env = coop_loc_env.parallel_env("walled_yard", max_cycles=30)
    print("estimators per robot:", env.config.estimators)
    obs, infos = env.reset(seed=0)
    rng = np.random.default_rng(0)
    while env.agents:
        actions = {a: rng.uniform(-1, 1, 2) for a in env.agents}
        obs, rewards, terminations, truncations, infos = env.step(actions)
    for agent, info in infos.items():
        print(f"{agent}: position error {info['position_error']:.2f} m, "
              f"localization reward {info['reward_localization']:.2f}")


if __name__ == "__main__":
    main()
