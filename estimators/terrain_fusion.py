"""Elevation fusion of DGPS altitude and inclinometer pitch (Madhavan, Fregene, Parker, Sec. 5.3).

The paper's elevation gradient is

    dZ = 0.5 * (f_theta * L * tan(theta) + f_gps * (Zg - Zg0))

with ``theta`` the inclinometer pitch, ``L`` the CG-to-camera offset, ``Zg``
the robot's DGPS altitude, ``Zg0`` the base station's, and weights set by the
number of satellites in view (NOS)::

    f_gps   = 0.1        if NOS <= 4;  NOS / 10      if 4 < NOS <= 10;  0.9 if NOS > 10
    f_theta = 0.9        if NOS <= 4;  1 - NOS / 10  if 4 < NOS <= 10;  0.1 if NOS > 10

:func:`fusion_weights` and :func:`paper_delta_z` implement these literally.
Note the paper's own quirk: at exactly 10 satellites ``f_gps = 1`` and
``f_theta = 0`` (the inclinometer is ignored), while at 11 the weights fall
back to 0.9 / 0.1. We keep it as published.

Interpretation used for mapping (:func:`fuse_elevation`)
--------------------------------------------------------
Taken literally, the formula adds a *vertical displacement* (``L tan theta``)
to an *absolute altitude* (``Zg - Zg0``) and halves the sum, so it cannot be
compared with a height field. We read it as a complementary filter between
two elevation estimates, weighted by the same satellite-count weights (which
sum to one, so the ``0.5`` is dropped to keep the estimate unbiased):

* inclinometer (dead reckoning): ``z_inc = z_prev + d * tan(theta)``, where
  ``d`` is the signed horizontal distance driven along the heading since the
  previous sample (the paper's lever arm ``L`` becomes the distance driven,
  so ``d tan(theta)`` is the rise over that step);
* DGPS: ``z_gps = datum + (Zg - Zg0)``, the altitude above the base station
  (``datum`` is the base station's elevation in the map frame, 0 by default);
* fused: ``z = f_theta * z_inc + f_gps * z_gps``.

Without a DGPS fix (``Zg`` NaN, or NOS = 0) the weights become
``f_theta = 1, f_gps = 0``: pure dead reckoning of elevation. The variance of
the result is propagated alongside (first order), with the DGPS altitude
variance inversely proportional to NOS, as the paper sets the DGPS position
variance. That variance feeds the map's confidence measure.

The paper's weights are not variance-optimal: with many satellites the noisy
DGPS altitude dominates even when the inclinometer track is better. For
comparison, ``weights="kalman"`` replaces them by the 1-D Kalman gain.
"""

from __future__ import annotations

import numpy as np

#: Satellite count at which ``gps_alt_std`` is specified (variance scales as ``REF_NOS / NOS``).
REF_NOS = 10.0


def _as_nos(nos: np.ndarray | float) -> np.ndarray:
    nos = np.asarray(nos, dtype=float)
    if np.count_nonzero((nos >= 0) & (nos < np.inf)) != nos.size:
        raise ValueError(f"nos must be finite and >= 0, got {nos!r}")
    return nos


def _gps_weight(nos: np.ndarray) -> np.ndarray:
    """``f_gps`` for validated counts; ``f_theta`` is always ``1 - f_gps``."""
    return np.where(nos > 10, 0.9, np.where(nos <= 4, 0.1, nos * 0.1))


def fusion_weights(nos: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """The paper's piecewise weights ``(f_theta, f_gps)`` for satellite counts ``nos``.

    Vectorized over ``nos``; raises ``ValueError`` for negative or non-finite
    counts. In every branch ``f_theta + f_gps = 1``.
    """
    f_gps = _gps_weight(_as_nos(nos))
    return 1.0 - f_gps, f_gps


def paper_delta_z(
    pitch: np.ndarray | float,
    lever_arm: float,
    gps_alt: np.ndarray | float,
    base_alt: float,
    nos: np.ndarray | float,
) -> np.ndarray:
    """Literal Eq. of Sec. 5.3: ``0.5 * (f_theta * L * tan(pitch) + f_gps * (Zg - Zg0))``.

    Kept for reference and comparison with the paper; the map uses
    :func:`fuse_elevation` (see the module docstring for why).
    """
    f_theta, f_gps = fusion_weights(nos)
    pitch = np.asarray(pitch, dtype=float)
    gps_alt = np.asarray(gps_alt, dtype=float)
    return 0.5 * (f_theta * lever_arm * np.tan(pitch) + f_gps * (gps_alt - base_alt))


def gps_alt_variance(nos: np.ndarray | float, gps_alt_std: float) -> np.ndarray:
    """DGPS altitude variance, inversely proportional to NOS: ``std^2 * REF_NOS / NOS``.

    ``gps_alt_std`` is the standard deviation at ``REF_NOS`` (10) satellites;
    zero satellites give an infinite variance.
    """
    nos = _as_nos(nos)
    with np.errstate(divide="ignore"):
        return gps_alt_std**2 * REF_NOS / nos


def fuse_elevation(
    prev_elev: np.ndarray,
    prev_var: np.ndarray,
    distance: np.ndarray,
    pitch: np.ndarray,
    gps_elev: np.ndarray,
    nos: np.ndarray,
    pitch_std: float,
    gps_alt_std: float,
    weights: str = "paper",
) -> tuple[np.ndarray, np.ndarray]:
    """One complementary-filter step of elevation per robot (all arguments shape ``(N,)``).

    Args:
        prev_elev, prev_var: elevation estimate and its variance after the previous sample.
        distance: signed horizontal distance driven along the heading since then (m).
        pitch: inclinometer pitch, nose up positive (rad).
        gps_elev: DGPS elevation in the map frame, ``datum + Zg - Zg0``; NaN = no fix.
        nos: satellites in view (0 = no fix).
        pitch_std: inclinometer noise standard deviation (rad).
        gps_alt_std: DGPS altitude noise standard deviation at 10 satellites (m).
        weights: ``"paper"`` for the satellite-count weights, or ``"kalman"``
            for the variance-optimal gain ``f_gps = var_inc / (var_inc + var_gps)``
            (a 1-D Kalman filter, for comparison with the paper's choice).

    Returns:
        ``(elev, var)``: fused elevation and its first-order variance.
    """
    if weights not in ("paper", "kalman"):
        raise ValueError(f"weights must be 'paper' or 'kalman', got {weights!r}")
    nos = np.asarray(nos, dtype=float)
    tan_p = np.tan(pitch)
    return fuse_elevation_tangents(
        prev_elev,
        prev_var,
        distance,
        tan_p,
        tan_p * tan_p,
        gps_elev,
        nos if np.count_nonzero(nos) else None,  # no satellites anywhere: no fix at all
        pitch_std,
        gps_alt_std,
        weights,
    )


def fuse_elevation_tangents(
    prev_elev: np.ndarray,
    prev_var: np.ndarray,
    distance: np.ndarray,
    tan_p: np.ndarray,
    tan2: np.ndarray,
    gps_elev: np.ndarray,
    nos: np.ndarray | None,
    pitch_std: float,
    gps_alt_std: float,
    weights: str,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fuse_elevation` (its one implementation) from ``tan_p = tan(pitch)``, ``tan2 =
    tan_p^2`` and a known ``weights``; ``nos`` None when no robot sees a satellite
    (``gps_elev`` is then ignored), otherwise checked here. Inputs are not modified."""
    z_inc = distance * tan_p
    z_inc += prev_elev
    # d/dtheta tan = sec^2, so var(d tan(theta)) = (d sec^2 sigma)^2 to first order.
    var_inc = tan2 + 1.0
    var_inc *= distance
    var_inc *= pitch_std
    var_inc *= var_inc
    var_inc += prev_var
    if nos is None:
        return z_inc, var_inc
    nos = _as_nos(nos)
    gps_elev = np.asarray(gps_elev, dtype=float)
    has_fix = (nos > 0) & (gps_elev == gps_elev)  # NaN != NaN
    if not np.count_nonzero(has_fix):  # f_gps = 0: the inclinometer alone
        return z_inc, var_inc
    z_gps = np.where(has_fix, gps_elev, 0.0)
    var_gps = (gps_alt_std * gps_alt_std * REF_NOS) / np.maximum(nos, 1e-12)
    if weights == "paper":
        f_gps = _gps_weight(nos) * has_fix
    else:
        total = var_inc + var_gps
        f_gps = np.where(total > 0, var_inc / np.where(total > 0, total, 1.0), 0.5) * has_fix
    f_theta = 1.0 - f_gps
    elev = f_theta * z_inc + f_gps * z_gps
    var = f_theta * f_theta * var_inc + f_gps * f_gps * var_gps
    return elev, var
