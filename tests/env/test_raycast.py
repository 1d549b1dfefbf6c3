"""Vectorized ray casting against analytic answers."""

import numpy as np
import pytest

from coop_loc_env.raycast import RayScene, cast, ray_circles, ray_segments


def test_ray_hits_circle_at_its_surface_and_misses_behind():
    origins = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    dirs = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]])
    d = ray_circles(origins, dirs, np.array([[5.0, 0.0]]), np.array([1.0]))
    assert d[0, 0] == pytest.approx(4.0)
    assert np.isinf(d[1, 0]) and np.isinf(d[2, 0])


def test_ray_from_inside_a_circle_exits_it():
    d = ray_circles(np.zeros((1, 2)), np.array([[0.0, 1.0]]), np.zeros((1, 2)), np.array([2.0]))
    assert d[0, 0] == pytest.approx(2.0)


def test_ray_segments_hit_within_and_miss_past_the_ends():
    a, b = np.array([[3.0, -1.0]]), np.array([[3.0, 1.0]])
    dirs = np.array([[1.0, 0.0], [np.cos(0.5), np.sin(0.5)], [0.0, 1.0]])
    d = ray_segments(np.zeros((3, 2)), dirs, a, b)
    assert d[0, 0] == pytest.approx(3.0)
    assert np.isinf(d[1, 0])  # passes above y = 1 at x = 3
    assert np.isinf(d[2, 0])  # parallel


def test_cast_excludes_own_robot_and_reports_robot_hits():
    scene = RayScene(
        circle_centers=np.array([[10.0, 0.0]]), circle_radii=np.array([1.0]),
        circle_mask=np.array([[True, False, True]]),
        seg_a=np.zeros((0, 2)), seg_b=np.zeros((0, 2)), seg_mask=np.zeros((0, 3), bool),
    )
    robots = np.array([[0.0, 0.0], [4.0, 0.0]])
    origins = robots[[0, 0]]
    dirs = np.array([[1.0, 0.0], [0.0, 1.0]])
    dist, hit = cast(scene, origins, dirs, 0, robots, np.array([0.5, 0.5]), np.array([0, 0]))
    assert dist[0] == pytest.approx(3.5) and hit[0] == 1
    assert np.isinf(dist[1]) and hit[1] == -1
    # The sonar channel does not see the circle (mask), so a ray past robot 1 misses.
    far = cast(scene, np.array([[0.0, 2.0]]), np.array([[1.0, 0.0]]), 1)[0]
    assert np.isinf(far[0])


def _circle_scene(centers: list, radii: list, bounds: tuple[float, float]) -> RayScene:
    """Circles that every channel sees, in a box, without segments."""
    return RayScene(
        circle_centers=np.array(centers, dtype=float), circle_radii=np.array(radii, float),
        circle_mask=np.ones((len(radii), 3), bool),
        seg_a=np.zeros((0, 2)), seg_b=np.zeros((0, 2)), seg_mask=np.zeros((0, 3), bool),
        bounds=bounds,
    )


def _random_scene(
    rng: np.random.Generator, n_circles: int, circle_mask: np.ndarray, n_segments: int
) -> RayScene:
    """Random circles (and segments) in a 20 m x 20 m box."""
    return RayScene(
        circle_centers=rng.uniform(0, 20, (n_circles, 2)),
        circle_radii=rng.uniform(0.1, 1.5, n_circles),
        circle_mask=circle_mask,
        seg_a=rng.uniform(0, 20, (n_segments, 2)), seg_b=rng.uniform(0, 20, (n_segments, 2)),
        seg_mask=np.ones((n_segments, 3), bool),
        bounds=(20.0, 20.0),
    )


def _poses_outside_circles(rng: np.random.Generator, scene: RayScene, n: int) -> np.ndarray:
    """``n`` random poses whose robots stand outside every circle of ``scene``."""
    spots = rng.uniform(0.5, 19.5, (400, 2))
    gap = np.linalg.norm(spots[:, None] - scene.circle_centers[None], axis=2) - scene.circle_radii
    spots = spots[gap.min(1) > 0.4]
    return np.column_stack([spots[:n], rng.uniform(-4, 4, n)])


@pytest.mark.parametrize("dense_limit", [0, 10**9])
@pytest.mark.parametrize("seed", range(5))
def test_fan_caster_matches_brute_force_cast(seed, dense_limit):
    """Culled fans give the same nearest hits as testing every ray against every shape."""
    from coop_loc_env.raycast import FanCaster

    rng = np.random.default_rng(seed)
    n_robots = 6
    scene = _random_scene(rng, 40, rng.random((40, 3)) < 0.7, n_segments=3)
    poses = _poses_outside_circles(rng, scene, n_robots)
    if dense_limit == 0:  # the culled path also handles a robot inside a circle
        poses[0, :2] = scene.circle_centers[0]
    # Mixed fans: 30 beams over 180 deg, and 8 x 3 sub-rays all around (wrapping past +-pi).
    ray_robot = np.concatenate([np.repeat([0, 1, 2], 30), np.repeat([3, 4, 5], 24)])
    laser = np.tile(np.linspace(-np.pi / 2, np.pi / 2, 30), 3)
    sonar = np.tile((np.arange(24) // 3) * np.pi / 4 + (np.arange(24) % 3 - 1) * 0.3 - np.pi, 3)
    ray_angle = np.concatenate([laser, sonar])
    radii = np.full(n_robots, 0.35)
    for channel in (0, 1):
        fan = FanCaster(scene, channel, ray_robot, ray_angle, np.full(len(ray_robot), 1e3))
        fan.dense_limit = dense_limit
        got = fan.cast(poses, poses[:, :2], radii)
        heading = poses[ray_robot, 2] + ray_angle
        dirs = np.stack([np.cos(heading), np.sin(heading)], 1)
        want, _ = cast(scene, poses[ray_robot, :2], dirs, channel, poses[:, :2], radii, ray_robot)
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("robots", [[0, 1, 2, 3], [1, 3, 4]])
@pytest.mark.parametrize("seed", range(3))
def test_equal_fans_match_brute_force_cast(seed, robots):
    """Equal fans, robot-major (the one-table path), also for a subset of the team."""
    from coop_loc_env.raycast import FanCaster

    rng = np.random.default_rng(seed)
    n_robots = 5
    scene = _random_scene(rng, 30, np.ones((30, 3), bool), n_segments=0)
    poses = _poses_outside_circles(rng, scene, n_robots)
    ray_robot = np.repeat(robots, 30)
    ray_angle = np.tile(np.linspace(-np.pi / 2, np.pi / 2, 30), len(robots))
    radii = np.full(n_robots, 0.35)
    fan = FanCaster(scene, 0, ray_robot, ray_angle, np.full(len(ray_robot), 1e3))
    assert fan.fans == (len(robots), 30, 2)
    got = fan.cast(poses, poses[:, :2], radii)
    heading = poses[ray_robot, 2] + ray_angle
    dirs = np.stack([np.cos(heading), np.sin(heading)], 1)
    want, _ = cast(scene, poses[ray_robot, :2], dirs, 0, poses[:, :2], radii, ray_robot)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    assert np.isfinite(got).all()  # the walls stop every ray


def test_fan_caster_ignores_circles_beyond_its_range_but_not_walls():
    from coop_loc_env.raycast import FanCaster

    scene = _circle_scene([[8.0, 5.0]], [1.0], (10.0, 10.0))
    pose = np.array([[2.0, 5.0, 0.0]])
    near = FanCaster(scene, 0, np.array([0]), np.array([0.0]), np.array([10.0]))
    far = FanCaster(scene, 0, np.array([0]), np.array([0.0]), np.array([3.0]))
    near.dense_limit = far.dense_limit = 0  # the culled path
    assert near.cast(pose)[0] == pytest.approx(5.0)
    assert far.cast(pose)[0] == pytest.approx(8.0)  # the wall at x = 10


def test_circles_block_agrees_with_nearest_ray_circle_hit():
    from coop_loc_env.raycast import circles_block

    rng = np.random.default_rng(3)
    centers = rng.uniform(0, 10, (15, 2))
    radii = rng.uniform(0.1, 1.0, 15)
    origins = rng.uniform(0, 10, (200, 2))
    origins[0] = centers[0]  # a ray starting inside a circle
    ang = rng.uniform(-np.pi, np.pi, 200)
    dirs = np.stack([np.cos(ang), np.sin(ang)], 1)
    reach = rng.uniform(-1, 8, 200)
    hit = ray_circles(origins, dirs, centers, radii).min(1)
    np.testing.assert_array_equal(circles_block(origins, dirs, centers, radii, reach), hit < reach)
    assert not circles_block(origins, dirs, centers[:0], radii[:0], reach).any()


def _fan_angles(fov: float, count: int) -> np.ndarray:
    """``count`` ray angles across ``fov`` (all around, without a duplicate, at 2 pi)."""
    if fov >= 2 * np.pi:
        return -np.pi + (np.arange(count) + 0.5) * 2 * np.pi / count
    return np.linspace(-fov / 2, fov / 2, count)


def _apart(scene: RayScene, poses: np.ndarray) -> bool:
    """Whether every robot stands in the box, clear of the circles and of the others."""
    xy = poses[:, :2]
    gap = np.linalg.norm(xy[:, None] - scene.circle_centers[None], axis=2) - scene.circle_radii
    mutual = np.linalg.norm(xy[:, None] - xy[None], axis=2) + 10 * np.eye(len(xy))
    return bool(((xy > 0.5) & (xy < 19.5)).all() and gap.min() > 0.05 and mutual.min() > 0.75)


@pytest.mark.parametrize("fov", [np.pi / 3, np.pi, 1.5 * np.pi, 2 * np.pi])
@pytest.mark.parametrize("robots", [[0, 1, 2, 3], [1, 3, 4]])
def test_equal_fans_keep_every_hit_within_reach_while_moving(fov, robots):
    """Candidate lists reused while robots drift, turn and jump lose no hit within the
    range: the same distances as the whole table and as brute force. (Up to rounding:
    numpy's matmul may round a table of one candidate circle differently, by an ulp.)"""
    from coop_loc_env.raycast import FanCaster

    rng = np.random.default_rng(int(fov * 10) + len(robots))
    n_robots, reach = 5, 6.0
    scene = _random_scene(rng, 60, np.ones((60, 3), bool), n_segments=0)
    poses = _poses_outside_circles(rng, scene, n_robots)
    while not _apart(scene, poses):
        poses = _poses_outside_circles(rng, scene, n_robots)
    angles = _fan_angles(fov, 24)
    ray_robot = np.repeat(robots, 24)
    ray_angle = np.tile(angles, len(robots))
    radii = np.full(n_robots, 0.35)
    fan = FanCaster(scene, 0, ray_robot, ray_angle, np.full(len(ray_robot), reach))
    whole = FanCaster(scene, 0, ray_robot, ray_angle, np.full(len(ray_robot), reach))
    whole.cull_fraction = -1.0  # never lists candidates
    listed = 0
    for step in range(80):
        if step % 25 == 24:  # a jump: the lists must be remade
            moved = _poses_outside_circles(rng, scene, n_robots)
        else:
            moved = poses + rng.normal(0, [0.12, 0.12, 0.15], poses.shape)
        if _apart(scene, moved):
            poses = moved
        got = fan.cast(poses, poses[:, :2], radii)
        listed += fan._near[3] is not None
        full = whole.cast(poses, poses[:, :2], radii)
        np.testing.assert_allclose(
            np.minimum(got, reach), np.minimum(full, reach), rtol=1e-13, atol=0.0
        )
        heading = poses[ray_robot, 2] + ray_angle
        dirs = np.stack([np.cos(heading), np.sin(heading)], 1)
        want, _ = cast(scene, poses[ray_robot, :2], dirs, 0, poses[:, :2], radii, ray_robot)
        np.testing.assert_allclose(np.minimum(got, reach), np.minimum(want, reach), rtol=1e-9)
    if fov <= np.pi:
        assert listed > 40  # the candidate lists were in use


def test_equal_fans_keep_circles_at_the_edge_of_the_fan_and_of_the_reach():
    """Circles just within the range, and just in front of a 180 deg fan's edge rays,
    are hit; those just beyond are culled (the walls answer instead)."""
    from coop_loc_env.raycast import FanCaster

    reach, r, eps = 5.0, 0.5, 1e-6
    centers = [
        [10.0 + reach + r - eps, 10.0],  # ahead, its near side just within the range
        [10.0 - r + eps, 10.0 + 3.0],  # left, its front just past the robot's line
        [10.0 - r - eps, 10.0 - 3.0],  # right, all of it just behind the robot
        [10.0, 10.0 - reach - r - eps],  # behind the right edge ray, just beyond the range
    ]
    scene = _circle_scene(centers, [r] * 4, (30.0, 20.0))
    poses = np.array([[10.0, 10.0, 0.0], [25.0, 5.0, np.pi]])
    angles = np.linspace(-np.pi / 2, np.pi / 2, 5)  # edge rays at +-90 deg
    fan = FanCaster(scene, 0, np.repeat([0, 1], 5), np.tile(angles, 2), np.full(10, reach))
    fan.cull_fraction = 1.0
    fan.move_skin = fan.turn_skin = 0.0  # lists exactly at the edges
    got = fan.cast(poses, poses[:, :2], np.full(2, 0.3))[:5]
    assert fan._near[3] is not None and fan._near[3].shape[1] == 2  # two circles listed
    assert got[2] == pytest.approx(reach - eps)  # straight ahead
    assert got[4] == pytest.approx(3.0 - np.sqrt(r * r - (r - eps) ** 2))  # left edge ray
    assert got[0] == pytest.approx(10.0) and got[0] > reach  # right edge ray: the wall
    fan.move_skin, fan.turn_skin = 0.5, 0.6  # wider lists from the next move, same hits
    again = fan.cast(poses, poses[:, :2], np.full(2, 0.3))[:5]
    assert fan._near[3].shape[1] == 2
    poses[1, 0] += 1e-6  # the other robot: a new list, robot 0 unmoved
    again = fan.cast(poses, poses[:, :2], np.full(2, 0.3))[:5]
    assert fan._near[3].shape[1] == 4
    np.testing.assert_array_equal(np.minimum(again, reach), np.minimum(got, reach))


def test_equal_fans_with_no_circle_within_reach_see_the_walls():
    """Empty candidate lists (no circle within any robot's range) leave only the walls."""
    from coop_loc_env.raycast import FanCaster

    scene = _circle_scene([[18.0, 18.0]], [0.5], (20.0, 20.0))
    fan = FanCaster(scene, 0, np.repeat([0, 1], 3), np.tile([-1.0, 0.0, 1.0], 2), np.full(6, 2.0))
    poses = np.array([[2.0, 2.0, 0.0], [2.0, 10.0, np.pi]])
    for extra in (None, poses[:, :2]):
        got = fan.cast(poses, extra, None if extra is None else np.full(2, 0.3))
        assert fan._near[3].shape == (2, 0)
        np.testing.assert_allclose(got[[1, 4]], [18.0, 2.0])  # straight ahead: the walls
