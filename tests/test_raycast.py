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

    scene = RayScene(
        circle_centers=np.array([[8.0, 5.0]]), circle_radii=np.array([1.0]),
        circle_mask=np.ones((1, 3), bool),
        seg_a=np.zeros((0, 2)), seg_b=np.zeros((0, 2)), seg_mask=np.zeros((0, 3), bool),
        bounds=(10.0, 10.0),
    )
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
