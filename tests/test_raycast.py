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
