"""The simulation experiments of Fox, Burgard, Kruppa and Thrun (their Figs. 12 and 13).

Both are global-localization tasks (``estimator="mcl"``, ``global_localization=True``):
every robot starts with particles spread uniformly over the free space of a
known map and has only odometry, a range finder and a robot detector (no DGPS,
compass, inclinometer or camera). The env step is 0.5 s so that episodes of
several simulated minutes stay cheap (600 s in the hallway, 300 s in the
hexagon); sensors fire once per step. Each robot keeps up to 2000 particles
in the hallway (4x as many at the start) and up to 5000 in the hexagon (10x at
the start); the MCL settings in ``extras`` are tuned for symmetric worlds (see
the comments in :func:`_common` and :func:`hexagon`).

* ``symmetric_hallway`` (Fig. 12): eight sonar robots in a square ring of
  2.5 m wide corridors around a 15 m x 15 m block. The ring is symmetric under
  quarter turns; the only feature that breaks the symmetry is an open area
  (a 4 m deep, 5 m long bay) off the left corridor, so a robot alone must pass
  it to know which corridor it is in (or see enough of it from a corner).
* ``hexagon`` (Fig. 13): a hexagonal room with 8 m edges, four sonar and four
  laser robots. Three sonar-only blocks (``visible_to=("sonar",)``) stand
  against the middle of every other edge, symmetric under thirds of a turn;
  four laser-only chamfers (``visible_to=("laser",)``) cut the corners at 0,
  60, 180 and 240 degrees, symmetric under half a turn only. As in the
  paper's Fig. 13(c, d), a sonar robot alone cannot tell three poses apart and
  a laser robot two; as the walls repeat every sixth of a turn, only the true
  pose is consistent with both, so a detection between robots of different
  types picks it (Eq. 10: the product of a two-mode and a three-mode belief
  has one common mode). The features are solid and flush with the walls, so
  robots that cannot see them rarely touch them. The MCL settings keep the
  symmetric copies alive and the detections tempered (see :func:`hexagon`).
"""

from __future__ import annotations

import math

from coop_loc_env.config import Obstacle, RobotSpec, ScenarioConfig
from coop_loc_env.scenarios import register_scenario, scenario_from_base


def _fox_robot(sensor: str) -> RobotSpec:
    """A robot with odometry, a ``sensor`` range finder and a robot detector only."""
    return RobotSpec(
        estimator="mcl",
        has_gps=False,
        has_compass=False,
        has_inclinometer=False,
        has_camera=False,
        has_detector=True,
        range_sensor=sensor,
    )


def _rect(x0: float, y0: float, x1: float, y1: float) -> Obstacle:
    return Obstacle("wall", "polygon", vertices=((x0, y0), (x1, y0), (x1, y1), (x0, y1)))


HALLWAY_SIZE = 20.0  # m, the square world
CORRIDOR = 2.5  # m, corridor width
BAY = (4.0, 5.0)  # m, depth and length of the open area off the left corridor


def hallway_obstacles() -> tuple[Obstacle, ...]:
    """The inner block of the ring (three rectangles leaving the bay open)."""
    s, c = HALLWAY_SIZE, CORRIDOR
    depth, length = BAY
    y0, y1 = s / 2 - length / 2, s / 2 + length / 2
    return (
        _rect(c + depth, c, s - c, s - c),  # the block east of the bay
        _rect(c, c, c + depth, y0),  # south of the bay
        _rect(c, y1, c + depth, s - c),  # north of the bay
    )


def _common() -> dict:
    """Settings shared by both experiments."""
    return dict(
        estimator="mcl",
        global_localization=True,
        dt=0.5,
        odometry_rate=10.0,
        laser_rate=2.0,
        detector_rate=2.0,
        camera_rate=2.0,
        gps_rate=1.0,
        compass_rate=1.0,
        inclinometer_rate=1.0,
        n_random_trees=0,
        n_random_rocks=0,
        n_random_ooi=0,
        terrain_amplitude=0.0,
        terrain_hills=0,
        steep_patches=0,
        max_speed=1.0,
        max_turn_rate=1.0,
        robot_radius=0.25,
        sonar_beams=16,
        sonar_fov_deg=360.0,
        sonar_max_range=6.0,
        sonar_range_std=0.15,
        laser_beams=30,
        laser_fov_deg=180.0,
        laser_max_range=10.0,
        laser_range_std=0.03,
        detector_range=6.0,
        detector_fov_deg=360.0,
        detection_model="fox",
        detection_range_std=0.3,
        detection_bearing_std=0.04,
        detection_orientation_std=0.1,
        n_particles=2000,
        reward_localization_weight=1.0,
        extras={
            "mcl_resolution": 0.25,
            # Confident observers re-seed 10 % of a detected robot's particles
            # (see MCLBackend._detection_reset); 0 gives the paper's pure transfer.
            "mcl_detection_reset": 0.1,
            # 16 sonar beams treated as independent are overconfident: temper them
            # (exponent 0.1) so that symmetric modes are not dropped too early; inject
            # few random particles (0.5 %, up to 10 % when the scans stop matching:
            # augmented MCL, which lets a robot locked onto a rotated copy of the
            # map recover when it reaches the feature that breaks the symmetry).
            "mcl": {
                "likelihood_exponent": 0.1,
                "beam_sigma": 0.5,
                "random_fraction": 0.005,
                "max_inject_fraction": 0.1,
            },
        },
    )


def symmetric_hallway() -> ScenarioConfig:
    """Eight sonar robots localize globally in a symmetric ring of corridors (Fig. 12)."""
    return ScenarioConfig(
        name="symmetric_hallway",
        n_robots=8,
        team=(_fox_robot("sonar"),),
        world_size=(HALLWAY_SIZE, HALLWAY_SIZE),
        obstacles=hallway_obstacles(),
        max_cycles=1200,  # 600 s, the horizon of the paper's Fig. 12(b)
        **_common(),
    )


HEX_EDGE = 8.0  # m
HEX_WORLD = (16.0, 14.0)  # m: the hexagon is 16 m x 13.86 m; whole metres keep the grid symmetric


def hexagon_vertices(edge: float = HEX_EDGE) -> list[tuple[float, float]]:
    """Corners of the flat-topped hexagon centred in the world, counter-clockwise from east."""
    cx, cy = HEX_WORLD[0] / 2, HEX_WORLD[1] / 2
    return [
        (cx + edge * math.cos(k * math.pi / 3), cy + edge * math.sin(k * math.pi / 3))
        for k in range(6)
    ]


SONAR_FEATURE_DEG = (30.0, 150.0, 270.0)  # three-fold: a sonar robot keeps three poses
SONAR_BLOCK = (2.5, 0.75)  # m, length along the wall and depth into the room
LASER_CORNERS = (0, 1, 3, 4)  # corners at 0, 60, 180, 240 degrees: a laser robot keeps two poses
LASER_CHAMFER = 2.0  # m along each edge (the cut is 1 m deep)


def _block(cx: float, cy: float, deg: float, r_out: float, length: float, depth: float
           ) -> tuple[tuple[float, float], ...]:
    """A ``length`` x ``depth`` rectangle facing the centre, its outer face ``r_out`` from it
    in direction ``deg`` (counter-clockwise vertices)."""
    a = math.radians(deg)
    u = (math.cos(a), math.sin(a))  # outward
    t = (-u[1], u[0])  # along the face
    pts = []
    for r, s in ((r_out - depth, -1), (r_out - depth, 1), (r_out, 1), (r_out, -1)):
        pts.append((cx + r * u[0] + s * length / 2 * t[0], cy + r * u[1] + s * length / 2 * t[1]))
    return tuple(pts)


def hexagon_obstacles(edge: float = HEX_EDGE) -> tuple[Obstacle, ...]:
    """Walls outside the hexagon, and the sonar-only / laser-only features."""
    w, h = HEX_WORLD
    v = hexagon_vertices(edge)
    outside = (
        Obstacle("wall", "polygon", vertices=((0.0, 0.0), (v[4][0], 0.0), v[4], v[3])),
        Obstacle("wall", "polygon", vertices=((v[5][0], 0.0), (w, 0.0), v[0], v[5])),
        Obstacle("wall", "polygon", vertices=(v[0], (w, h), (v[1][0], h), v[1])),
        Obstacle("wall", "polygon", vertices=(v[3], v[2], (v[2][0], h), (0.0, h))),
        _rect(v[4][0], 0.0, v[5][0], v[4][1]),  # thin strips along the flat edges
        _rect(v[2][0], v[2][1], v[1][0], h),
    )
    cx, cy = w / 2, h / 2
    features = []
    # sonar-only: a block against the middle of every other edge (30, 150, 270 degrees)
    for deg in SONAR_FEATURE_DEG:
        features.append(Obstacle("wall", "polygon", visible_to=("sonar",),
                                 vertices=_block(cx, cy, deg, edge * math.sqrt(3) / 2,
                                                 *SONAR_BLOCK)))
    # laser-only: the corners at 0 and 180 degrees cut off (a chamfer LASER_CHAMFER m along
    # each edge), so a laser robot sees a flat face there instead of a corner
    for k in LASER_CORNERS:
        c, prev, nxt = v[k], v[(k - 1) % 6], v[(k + 1) % 6]
        f = LASER_CHAMFER / edge
        features.append(Obstacle("wall", "polygon", visible_to=("laser",), vertices=(
            c, (c[0] + f * (nxt[0] - c[0]), c[1] + f * (nxt[1] - c[1])),
            (c[0] + f * (prev[0] - c[0]), c[1] + f * (prev[1] - c[1])),
        )))
    return outside + tuple(features)


def hexagon() -> ScenarioConfig:
    """Four sonar and four laser robots in a symmetric hexagon with 8 m edges (Fig. 13)."""
    common = _common()
    extras = common["extras"]
    # Every pose in the hexagon has two (laser) or three (sonar) exact copies, and a
    # robot alone must keep all of them (the paper's Fig. 13(c, d)) until a detection
    # picks the one consistent with a robot of the other type:
    # * no random injection: injected particles land on copies that fit as well as
    #   the truth and split a tracked belief;
    # * many particles: 50 000 at the start (so every copy of the true pose is
    #   sampled densely), then KLD-sampling between 2000 and 5000 (each of up to six
    #   copies keeps hundreds of particles, so resampling noise does not drift them
    #   apart); scans tempered harder (exponent 0.05) so that the copies' weights,
    #   equal in theory, do not diverge through sampling noise;
    # * lasers use the beam model (the paper's Fig. 1) with a 0.3 m Gaussian: the
    #   likelihood field scores beam endpoints inside the solid outside of the room
    #   as hits, so poses whose beams pass through a wall fit as well as the truth.
    extras["mcl"].update(random_fraction=0.0, augmented=False, likelihood_exponent=0.05,
                         n_min=2000)
    # Detections are tempered too (exponent 0.2): relative detections cannot tell a
    # rotated copy of the whole team from the truth, only the robots' own scans can;
    # a robot here is detected about every 1.5 s (360-degree detector, 8 robots in
    # one room), and untempered, those repeated transfers (each re-importing the
    # same beliefs) outvote the tempered scans and the team settles on whichever
    # frame it first agrees on.
    extras.update(mcl_global_init_factor=10, mcl_laser_model="beam",
                  mcl_laser={"beam_sigma": 0.3}, mcl_detection_exponent=0.2)
    common["n_particles"] = 5000
    return ScenarioConfig(
        name="hexagon",
        n_robots=8,
        team=(_fox_robot("sonar"), _fox_robot("laser")),
        world_size=HEX_WORLD,
        obstacles=hexagon_obstacles(),
        max_cycles=600,
        **common,
    )


register_scenario("symmetric_hallway", scenario_from_base(symmetric_hallway))
register_scenario("hexagon", scenario_from_base(hexagon))
