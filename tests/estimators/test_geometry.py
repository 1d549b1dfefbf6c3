"""Angle wrapping at the edges of its documented range ``[-pi, pi)``."""

import math

import numpy as np

from estimators.geometry import wrap_angle, wrap_angle_in_place


def _edge_angles() -> np.ndarray:
    """Angles a few ulps around odd multiples of pi, where the shifted remainder rounds."""
    out = []
    for k in (-7, -5, -3, -1, 1, 3, 5):
        centre = k * math.pi
        below, above = centre, centre
        for _ in range(4):
            below, above = math.nextafter(below, -math.inf), math.nextafter(above, math.inf)
            out += [below, above]
        out.append(centre)
    return np.array(out + [-math.pi - 4e-16, -math.pi - 1e-16, math.pi - 4e-16])


def test_wrap_angle_stays_below_pi_near_minus_pi():
    assert wrap_angle(-math.pi - 4e-16) < math.pi
    assert -math.pi <= wrap_angle(-math.pi - 4e-16)
    angles = _edge_angles()
    wrapped = wrap_angle(angles)
    assert wrapped.min() >= -math.pi and wrapped.max() < math.pi
    # Still the same angle: the wrap moves each by a multiple of 2 pi (to rounding).
    turns = (angles - wrapped) / (2 * math.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-12)


def test_wrap_angle_in_place_stays_below_pi_and_matches():
    angles = _edge_angles()
    out = angles.copy()
    wrap_angle_in_place(out)
    assert out.min() >= -math.pi and out.max() < math.pi
    np.testing.assert_array_equal(out, wrap_angle(angles))


def test_wrap_angle_leaves_the_range_itself_alone():
    inside = np.array([-math.pi, -1.0, 0.0, 1.0, 3.0])
    np.testing.assert_array_equal(wrap_angle(inside), inside)
    assert wrap_angle(math.pi) == -math.pi
