"""Compiled loops (numba, cached on disk) of the terrain map's per-step update.

Each does in one pass what a chain of small numpy operations would, with the same
IEEE operations in the same order (no fast-math, no fused multiply-adds), so the
result is bit-identical to the numpy code of
:meth:`estimators.terrain_map.TerrainMap.update_prepared` it serves; the trigonometry
stays in numpy.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["footprint_samples", "fuse_without_fix"]


@njit(cache=True)
def footprint_samples(
    poses: np.ndarray, elev: np.ndarray, var_s: np.ndarray, tan_p: np.ndarray,
    cos_h: np.ndarray, sin_h: np.ndarray, fp: np.ndarray, fp_var: np.ndarray,
    origin: np.ndarray, inv_res: float, nx: int, ny: int, ids: np.ndarray,
    stored_conf: np.ndarray, flat: np.ndarray, vals: np.ndarray, conf: np.ndarray,
    owner: np.ndarray,
) -> tuple[int, bool]:  # pragma: no cover (compiled)
    """Each robot's footprint samples, those inside the grid compacted in order.

    Robot ``r`` (pose ``poses[r]``, fused elevation ``elev[r]``, sample variance
    ``var_s[r]``, ``tan_p[r]`` of its pitch, ``cos_h``/``sin_h`` of its heading)
    samples cell ``poses[r, :2] + fp[j]`` with value ``elev + tan_p (cos fp_x +
    sin fp_y)`` and confidence ``1 / (var_s + fp_var[j])``; ``origin`` is the
    grid's origin (empty: ``(0, 0)``). Writes the flat cell, value, confidence
    and robot id (``ids[r]``) of the samples inside the ``nx x ny`` grid into the
    fronts of ``flat``, ``vals``, ``conf`` and ``owner``; returns how many there
    are and whether any beats the confidence ``stored_conf`` holds for its cell.
    """
    n_fp = fp.shape[0]
    m = 0
    win = False
    shifted = origin.size > 0
    for r in range(poses.shape[0]):
        c = cos_h[r]
        s = sin_h[r]
        for j in range(n_fp):
            fx = poses[r, 0] + fp[j, 0]
            fy = poses[r, 1] + fp[j, 1]
            if shifted:
                fx -= origin[0]
                fy -= origin[1]
            fx *= inv_res
            fy *= inv_res
            if not (fx >= 0.0 and fx < nx and fy >= 0.0 and fy < ny):
                continue
            v = c * fp[j, 0]
            v += s * fp[j, 1]
            v *= tan_p[r]
            v += elev[r]
            w = var_s[r] + fp_var[j]
            w = 1.0 / w
            cell = int(fx) * ny + int(fy)
            flat[m] = cell
            vals[m] = v
            conf[m] = w
            owner[m] = ids[r]
            if w > stored_conf[cell]:
                win = True
            m += 1
    return m, win


_SAFE = 1e300  # below this, sums of a few thousand values cannot overflow


@njit(cache=True)
def fuse_without_fix(
    prev_elev: np.ndarray, prev_var: np.ndarray, distance: np.ndarray, tan_p: np.ndarray,
    tan2: np.ndarray, slope2: np.ndarray, pos_var: np.ndarray, pitch_std: float,
    min_var: float, poses: np.ndarray, elev: np.ndarray, var: np.ndarray, var_s: np.ndarray,
) -> bool:  # pragma: no cover (compiled)
    """The inclinometer-only elevation fusion and the sample variances, when no robot has
    a fix (as :func:`estimators.terrain_fusion.fuse_elevation_tangents` and
    :meth:`estimators.terrain_map.TerrainMap.update_prepared` compute them).

    Writes ``elev``, ``var`` (the fused elevation and its variance) and ``var_s`` (the
    sample variance, floored at ``min_var``); returns whether every value and pose is
    finite and far from overflow, i.e. the caller's finiteness check passes for sure
    (False: run the numpy path, which decides).
    """
    ok = True
    for r in range(distance.size):
        z = distance[r] * tan_p[r]
        z += prev_elev[r]
        v = tan2[r] + 1.0
        v *= distance[r]
        v *= pitch_std
        v *= v
        v += prev_var[r]
        s = slope2[r] * pos_var[r]
        s += v
        if s < min_var:  # np.maximum: NaN stays NaN
            s = min_var
        elev[r] = z
        var[r] = v
        var_s[r] = s
        ok &= abs(z) < _SAFE and abs(s) < _SAFE
        for c in range(poses.shape[1]):
            ok &= abs(poses[r, c]) < _SAFE
    return ok
