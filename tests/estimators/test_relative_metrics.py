"""Tests of the Eq. 15 relative-pose error metrics."""

import numpy as np
import pytest

from estimators.relative_metrics import (
    ERROR_NAMES,
    pairwise_errors,
    relative_error_dict,
    relative_errors,
    relative_errors_per_robot,
    relative_matrix_errors,
    relative_pose_matrix,
)


def _rigid(poses: np.ndarray, angle: float, shift: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    out = poses.copy()
    out[..., 0] = c * poses[..., 0] - s * poses[..., 1] + shift[0]
    out[..., 1] = s * poses[..., 0] + c * poses[..., 1] + shift[1]
    out[..., 2] = poses[..., 2] + angle
    return out


def test_relative_pose_matrix_hand_example():
    poses = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, np.pi / 2]])
    rel = relative_pose_matrix(poses)
    assert rel.shape == (2, 2, 3)
    np.testing.assert_allclose(rel[0, 1], [5.0, np.arctan2(4, 3), np.pi / 2])
    # seen from robot 1 (facing +y), robot 0 is behind-left: bearing atan2(-4,-3) - pi/2
    expected_bearing = np.arctan2(-4.0, -3.0) - np.pi / 2 + 2 * np.pi
    np.testing.assert_allclose(rel[1, 0], [5.0, expected_bearing, -np.pi / 2])
    np.testing.assert_allclose(rel[0, 0], 0.0)


def test_errors_vanish_for_truth_and_any_rigid_transform():
    rng = np.random.default_rng(3)
    truth = rng.uniform(-5, 5, (6, 3))
    np.testing.assert_allclose(relative_errors(truth, truth), 0.0)
    moved = _rigid(truth, 2.5, np.array([10.0, -3.0]))
    np.testing.assert_allclose(relative_errors(moved, truth), 0.0, atol=1e-12)


def test_known_perturbation_gives_hand_computed_errors():
    truth = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    est = truth.copy()
    est[1, 0] = 3.0  # robot 1 one metre further along x
    err = pairwise_errors(est, truth)
    assert err[0, 1, 0] == pytest.approx(1.0)  # range 2 -> 3
    assert err[0, 1, 1] == pytest.approx(0.0)  # bearing 0 unchanged
    r_new = np.hypot(3.0, 2.0)
    assert err[2, 1, 0] == pytest.approx(r_new - np.hypot(2.0, 2.0))
    # ranges: pairs (0,1),(1,0) err 1; (1,2),(2,1) err r_new - 2 sqrt2; (0,2),(2,0) err 0
    expected_range = (2 * 1.0 + 2 * (r_new - 2 * np.sqrt(2.0))) / 6
    e_r, e_b, e_o = relative_errors(est, truth)
    assert e_r == pytest.approx(expected_range)
    assert e_o == pytest.approx(0.0)
    assert e_b > 0.0


def test_angle_errors_are_wrapped():
    truth = np.array([[0.0, 0.0, np.pi - 0.01], [1.0, 0.0, 0.0]])
    est = truth.copy()
    est[0, 2] = -np.pi + 0.01  # 0.02 rad away across the cut
    e_r, e_b, e_o = relative_errors(est, truth)
    assert e_r == pytest.approx(0.0)
    assert e_o == pytest.approx(0.02, abs=1e-9)
    assert e_b == pytest.approx(0.01, abs=1e-9)  # only robot 0's bearing of robot 1 changes


def test_leading_axes_mask_and_per_robot():
    rng = np.random.default_rng(5)
    truth = rng.uniform(-5, 5, (4, 5, 3))  # 4 time steps, 5 robots
    est = truth + rng.normal(0.0, 0.1, truth.shape)
    series = relative_errors(est, truth)
    assert series.shape == (4, 3)
    np.testing.assert_allclose(series[2], relative_errors(est[2], truth[2]))
    per = relative_errors_per_robot(est, truth)
    assert per.shape == (4, 5, 3)
    np.testing.assert_allclose(per.mean(axis=1), series)  # equal pair counts per robot
    mask = np.array([True, True, False, True, False])
    masked = relative_errors(est[0], truth[0], mask=mask)
    np.testing.assert_allclose(masked, relative_errors(est[0][mask], truth[0][mask]))
    d = relative_error_dict(est[0], truth[0])
    assert list(d) == list(ERROR_NAMES)
    assert d["relative_range_error"] == pytest.approx(series[0, 0])


@pytest.mark.parametrize(
    "est, truth",
    [
        (np.zeros((3, 3)), np.zeros((4, 3))),
        (np.zeros((1, 3)), np.zeros((1, 3))),
        (np.zeros((3, 2)), np.zeros((3, 2))),
        (np.full((3, 3), np.nan), np.zeros((3, 3))),
    ],
)
def test_bad_input_raises(est, truth):
    with pytest.raises(ValueError):
        relative_errors(est, truth)


def test_mask_leaving_one_robot_raises():
    poses = np.zeros((3, 3))
    with pytest.raises(ValueError, match="two robots"):
        relative_errors(poses, poses, mask=np.array([True, False, False]))


def test_diagonal_is_zero_even_with_headings():
    poses = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, -2.0], [3.0, 0.0, 3.0]])
    rel = relative_pose_matrix(poses[None])  # with a leading axis
    np.testing.assert_array_equal(rel[0, [0, 1, 2], [0, 1, 2]], 0.0)
    err = pairwise_errors(poses, poses + [0.0, 0.0, 0.5])
    np.testing.assert_array_equal(err[[0, 1, 2], [0, 1, 2]], 0.0)


def test_matrix_form_agrees_with_pose_form():
    rng = np.random.default_rng(8)
    truth = rng.uniform(-5, 5, (3, 4, 3))
    est = truth + rng.normal(0.0, 0.2, truth.shape)
    np.testing.assert_allclose(
        relative_matrix_errors(relative_pose_matrix(est), relative_pose_matrix(truth)),
        relative_errors(est, truth),
    )
    with pytest.raises(ValueError):
        relative_matrix_errors(np.zeros((3, 4, 3)), np.zeros((3, 4, 3)))
