"""The two experiments of Howard, Mataric and Sukhatme (team localization by MLE).

Both are flat and indoor, with the paper's sensors only: odometry and a robot
detector (laser plus retro-reflective barcodes: identity, range, bearing and
orientation of teammates in view, 180 degree field of view, walls block it)
with ``detection_model="howard"``: range noise proportional to range (5 %),
constant bearing and orientation noise. No GPS, compass, inclinometer or
camera; the laser range finder is kept for obstacle avoidance. The team runs
the centralized MLE (``estimator="mle"``, :mod:`coop_loc_env.backends.mle`).

Odometry runs at 10 Hz (one physics substep per env step) with small additive
encoder noise (``odom_v_std = 0.01`` m/s, ``odom_w_std = 0.02`` rad/s) and a
large multiplicative wheel slip (``slip_std = 0.25`` per 0.1 s step, about 8 %
over a second), so dead-reckoning error grows with the distance driven while a
robot that stands still stays (nearly) put.

* ``dispersal``: 20 robots start crowded in one 8 m x 10 m room (bottom left)
  of a 32 m x 20 m building of eight rooms joined by doorways, then spread out
  (drive them with :class:`policies.scripted.dispersal.DispersalPolicy`). Expected
  (paper): relative error lowest while crowded, growing as they spread.
* ``circuit``: 7 robots around a 18 m x 10 m block. Six stand still at fixed
  places along the outer wall, out of each other's detector range (and sight);
  the seventh (``robot_6``) drives the ~76 m loop around the block past each of
  them and back to the first (:class:`policies.scripted.circuit.CircuitPolicy`).
  Expected (paper): error drops at each sighting, sharply at loop closure.
  The start-pose priors are weak (``init_pos_std = 2 m``) so that, as in the
  paper, the stationary robots' relative poses come from the sightings.
"""

from __future__ import annotations

import math

from coop_loc_env.config import Obstacle, RobotSpec, ScenarioConfig
from coop_loc_env.scenarios import register_scenario, scenario_from_base

#: Sensors of Howard et al.'s robots: odometry, laser (for avoidance) and the robot detector.
HOWARD_ROBOT = RobotSpec(
    has_gps=False,
    has_compass=False,
    has_inclinometer=False,
    has_range_sensor=True,
    range_sensor="laser",
    has_camera=False,
    has_detector=True,
)

WALL_HALF_THICKNESS = 0.05
DOOR_WIDTH = 2.4

# --- dispersal building: 4 x 2 rooms of 8 m x 10 m
BUILDING_SIZE = (32.0, 20.0)
ROOM_SIZE = (8.0, 10.0)
START_ROOM = (0.4, 0.4, 7.6, 9.6)

# --- circuit: a block in the middle, the loop 2.5 m around it
CIRCUIT_WORLD = (30.0, 22.0)
CIRCUIT_BLOCK = (6.0, 6.0, 24.0, 16.0)
CIRCUIT_LOOP = ((3.5, 3.5), (26.5, 3.5), (26.5, 18.5), (3.5, 18.5))
"""Corners of the driven loop, counter-clockwise from the start corner."""
DRIVER = 6


def _wall(a: tuple[float, float], b: tuple[float, float]) -> Obstacle:
    return Obstacle("wall", "segment", a=a, b=b, radius=WALL_HALF_THICKNESS)


def _wall_with_door(
    a: tuple[float, float], b: tuple[float, float], door_at: float
) -> list[Obstacle]:
    """Two wall segments from ``a`` to ``b`` leaving a door of ``DOOR_WIDTH`` centred at
    fraction ``door_at`` along it."""
    length = math.dist(a, b)
    ux, uy = (b[0] - a[0]) / length, (b[1] - a[1]) / length
    c = door_at * length
    d0, d1 = c - DOOR_WIDTH / 2, c + DOOR_WIDTH / 2
    return [
        _wall(a, (a[0] + ux * d0, a[1] + uy * d0)),
        _wall((a[0] + ux * d1, a[1] + uy * d1), b),
    ]


def building_walls() -> tuple[Obstacle, ...]:
    """Interior walls of the dispersal building: 4 x 2 rooms, a door in every shared wall."""
    w, h = BUILDING_SIZE
    rw, rh = ROOM_SIZE
    walls: list[Obstacle] = []
    for i in range(1, int(w / rw)):  # vertical walls, a door into each room row
        x = i * rw
        for j in range(int(h / rh)):
            walls += _wall_with_door((x, j * rh), (x, (j + 1) * rh), 0.5)
    for j in range(1, int(h / rh)):  # horizontal walls, a door into each room column
        y = j * rh
        for i in range(int(w / rw)):
            walls += _wall_with_door((i * rw, y), ((i + 1) * rw, y), 0.5)
    return tuple(walls)


def _howard_base(**kw) -> ScenarioConfig:
    base = dict(
        team=(HOWARD_ROBOT,),
        estimator="mle",
        n_random_trees=0,
        n_random_rocks=0,
        n_random_ooi=0,
        terrain_amplitude=0.0,
        terrain_hills=0,
        steep_patches=0,
        max_speed=0.5,
        max_turn_rate=1.0,
        robot_radius=0.25,
        odometry_rate=10.0,
        odom_v_std=0.01,
        odom_w_std=0.02,
        slip_std=0.25,
        laser_beams=24,
        laser_max_range=8.0,
        laser_fov_deg=360.0,
        detector_rate=10.0,
        detector_range=6.0,
        detector_fov_deg=180.0,
        detection_model="howard",
        detection_range_fraction=0.05,
        detection_bearing_std=0.035,
        detection_orientation_std=0.1,
        detection_prob=1.0,
        false_positive_prob=0.0,
        gate_prob=0.999,
        laser_obs_bins=12,
    )
    base.update(kw)
    return ScenarioConfig(**base)


def dispersal() -> ScenarioConfig:
    """20 robots start crowded in one room of an eight-room building and spread out."""
    return _howard_base(
        name="dispersal",
        n_robots=20,
        world_size=BUILDING_SIZE,
        layout_seed=0,
        obstacles=building_walls(),
        start_region=START_ROOM,
        max_cycles=1200,
        init_pos_std=0.5,
        init_heading_std=0.1,
    )


def circuit_start_poses() -> tuple[tuple[float, float, float], ...]:
    """Six stationary robots by the outer wall facing the loop, then the driver.

    Robot 0 stands by the start of the loop; the others are spread along it
    more than ``detector_range`` apart; the driver starts 2.5 m from robot 0,
    heading along the first leg.
    """
    stationary = (
        (6.0, 1.0, math.pi / 2),  # 0: bottom leg, near the start corner
        (18.5, 1.0, math.pi / 2),  # 1: bottom leg
        (29.0, 8.0, math.pi),  # 2: right leg
        (21.0, 21.0, -math.pi / 2),  # 3: top leg
        (9.0, 21.0, -math.pi / 2),  # 4: top leg
        (1.0, 12.0, 0.0),  # 5: left leg
    )
    driver = (CIRCUIT_LOOP[0][0] - 1.0, CIRCUIT_LOOP[0][1], 0.0)
    return (*stationary, driver)


def circuit() -> ScenarioConfig:
    """Six stationary robots out of each other's range; a seventh drives a loop past them."""
    x0, y0, x1, y1 = CIRCUIT_BLOCK
    block = Obstacle("building", "polygon", vertices=((x0, y0), (x1, y0), (x1, y1), (x0, y1)))
    return _howard_base(
        name="circuit",
        n_robots=7,
        world_size=CIRCUIT_WORLD,
        layout_seed=0,
        obstacles=(block,),
        start_poses=circuit_start_poses(),
        max_cycles=1800,
        init_pos_std=2.0,
        init_heading_std=0.3,
    )


register_scenario("dispersal", scenario_from_base(dispersal))
register_scenario("circuit", scenario_from_base(circuit))
