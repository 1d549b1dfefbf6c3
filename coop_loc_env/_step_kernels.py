"""Compiled loops (numba, cached on disk) of the env step's hot paths.

Each kernel fuses a chain of elementwise numpy operations into one pass, with
the same IEEE operations in the same order (no fast-math: no reassociation,
no fused multiply-adds), so results are bit-identical to the same chain in
numpy. Trigonometry and matrix products stay in numpy (their vectorized
implementations round differently from a scalar loop's). Private helpers of
:mod:`coop_loc_env.raycast`, :mod:`coop_loc_env.world`,
:mod:`coop_loc_env.backends`, :mod:`coop_loc_env.terrain`,
:mod:`coop_loc_env.mapping`, :mod:`coop_loc_env.sensors` and
:mod:`coop_loc_env.observations`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.geometry import PI_BELOW as _PI_BELOW

__all__ = [
    "circle_ray_hits", "cover_footprints", "fan_inputs", "fan_ranges", "gaussian_rows",
    "near_pairs", "noisy_ranges_into", "odometry_variance_into", "pack_observations",
    "pool_scans", "settle_poses", "steep_candidates", "substep_commands", "substep_velocities",
]

_PI = np.pi
_TWO_PI = 2.0 * np.pi


@njit(cache=True, error_model="numpy")
def fan_ranges(
    b: np.ndarray, rel: np.ndarray, r2: np.ndarray, dirs: np.ndarray, pose: np.ndarray,
    box: np.ndarray, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Nearest circle or wall along each ray of equal fans, into ``out`` ``(robots, rays)``.

    ``b`` ``(K, robots, rays)`` holds ``u . (c - o)`` of each candidate circle,
    ``rel`` ``(robots, K, 2)`` the candidates' ``c - o``, ``r2`` ``(robots, K)``
    their squared radii (``-inf``: a slot no ray hits), ``dirs`` ``(2, robots,
    rays)`` the rays' (cos, sin) and ``pose`` ``(robots, 3)`` the fans' poses.
    A ray hits a circle at ``t = b - sqrt(b^2 - q)``, ``q = |c - o|^2 - r^2``;
    the nearest hit is the largest positive ``1 / t`` (``inf`` without one).
    ``box`` is the world box ``(w, h)``, empty for none: the distance is then
    the smaller of that and the distance to the box's walls (NaN propagates).
    """
    n_k, n_fans, n_rays = b.shape
    inv = np.empty(n_rays)
    for f in range(n_fans):
        inv[:] = 0.0
        for k in range(n_k):
            qx = rel[f, k, 0]
            qy = rel[f, k, 1]
            q = qx * qx + qy * qy
            q -= r2[f, k]
            for j in range(n_rays):
                bj = b[k, f, j]
                disc = bj * bj - q
                t = 1.0 / (bj - math.sqrt(disc))
                if t > inv[j]:  # NaN (a miss) never is
                    inv[j] = t
        for j in range(n_rays):
            d = 1.0 / inv[j]
            if box.size:
                for axis in range(2):
                    c = dirs[axis, f, j]
                    wall = abs(((box[axis] if c > 0 else 0.0) - pose[f, axis]) / c)
                    if wall < d or wall != wall:  # np.minimum: NaN wins, then the smaller
                        d = wall
            out[f, j] = d


@njit(cache=True)
def substep_commands(
    v_cmd: np.ndarray, w_cmd: np.ndarray, slip: np.ndarray, slip_std: float,
    angles: np.ndarray, dt: float, vk: np.ndarray, wk: np.ndarray, heading: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Slipping commands and the headings at each substep's start (:meth:`World.step`).

    ``slip`` ``(T, n, 2)`` standard normals; writes ``vk``, ``wk`` ``(T, n)`` (the
    commands times ``1 + slip_std * noise``) and ``heading`` ``(T + 1, n)``: the
    unwrapped ``angles`` followed by the running sum of ``wk * dt``.
    """
    n_sub, n, _ = slip.shape
    for r in range(n):
        heading[0, r] = angles[r]
    for t in range(n_sub):
        for r in range(n):
            s_v = slip[t, r, 0] * slip_std
            s_v += 1.0
            s_w = slip[t, r, 1] * slip_std
            s_w += 1.0
            vk[t, r] = v_cmd[r] * s_v
            wk[t, r] = w_cmd[r] * s_w
            heading[t + 1, r] = heading[t, r] + wk[t, r] * dt


@njit(cache=True)
def substep_velocities(vel: np.ndarray, vk: np.ndarray, wk: np.ndarray) -> None:  # pragma: no cover
    """``vel`` ``(T, n, 3)`` holding (cos, sin) of the headings becomes the bodies'
    velocities ``(vk cos, vk sin, wk)``."""
    n_sub, n = vk.shape
    for t in range(n_sub):
        for r in range(n):
            vel[t, r, 0] *= vk[t, r]
            vel[t, r, 1] *= vk[t, r]
            vel[t, r, 2] = wk[t, r]


@njit(cache=True)
def settle_poses(
    state: np.ndarray, poses: np.ndarray, angles: np.ndarray, counts: np.ndarray,
    before: np.ndarray, touching: np.ndarray, new: np.ndarray, in_contact: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """The world's state after a step: ``poses`` from pymunk's ``state`` (headings
    wrapped to ``[-pi, pi)``, the unwrapped ones kept in ``angles``), the new contacts
    ``new = counts - before`` and ``in_contact = touching | (new > 0)``."""
    n = poses.shape[0]
    for r in range(n):
        poses[r, 0] = state[r, 0]
        poses[r, 1] = state[r, 1]
        a = state[r, 2]
        angles[r] = a
        h = a + _PI
        h %= _TWO_PI
        h -= _PI
        poses[r, 2] = h if h < _PI_BELOW or h != h else _PI_BELOW
        new[r] = counts[r] - before[r]
        in_contact[r] = touching[r] or new[r] > 0


@njit(cache=True, inline="always")
def _floored(v: float) -> float:  # pragma: no cover (compiled)
    """``np.maximum(v, 1e-12)`` (NaN stays NaN)."""
    return 1e-12 if v < 1e-12 else v


@njit(cache=True)
def gaussian_rows(
    mean: np.ndarray, flat: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray,
    log_var: np.ndarray, scale: np.ndarray, shift: np.ndarray, low: np.ndarray,
    high: np.ndarray, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Rows of :func:`coop_loc_env.backends.base.gaussian_features` into ``out`` ``(k, 10)``.

    ``flat`` ``(k, 9)``: the row-major covariances; ``log_var`` ``(k, 3)``: log10 of
    their variances floored at 1e-12; ``cos_h``, ``sin_h`` of the headings. Each
    column is then scaled, shifted and clipped (NaN stays NaN).
    """
    k = mean.shape[0]
    for r in range(k):
        s0 = math.sqrt(_floored(flat[r, 0]))
        s1 = math.sqrt(_floored(flat[r, 4]))
        s2 = math.sqrt(_floored(flat[r, 8]))
        out[r, 0] = mean[r, 0]
        out[r, 1] = mean[r, 1]
        out[r, 2] = cos_h[r]
        out[r, 3] = sin_h[r]
        out[r, 4] = log_var[r, 0]
        out[r, 5] = log_var[r, 1]
        out[r, 6] = log_var[r, 2]
        out[r, 7] = flat[r, 1] / (s0 * s1)
        out[r, 8] = flat[r, 2] / (s0 * s2)
        out[r, 9] = flat[r, 5] / (s1 * s2)
        for c in range(10):
            x = out[r, c] * scale[c]
            x -= shift[c]
            if x < low[c]:  # np.maximum then np.minimum: NaN passes both
                x = low[c]
            if x > high[c]:
                x = high[c]
            out[r, c] = x


@njit(cache=True)
def steep_candidates(
    points: np.ndarray, inv_res: float, f_max: np.ndarray, strides: np.ndarray,
    steep_cells: np.ndarray, among: np.ndarray, out: np.ndarray,
) -> bool:  # pragma: no cover (compiled)
    """Which ``points`` ``(k, 2)`` lie in a height-field cell that may be steep (and are
    ``among``, a mask; empty: all), into ``out`` ``(k,)``, as
    :meth:`coop_loc_env.terrain.HeightField.is_steep` tests first. Returns whether any
    does, or a coordinate is NaN (the caller then runs the full test)."""
    found = False
    for r in range(points.shape[0]):
        index = 0
        for axis in range(2):
            f = points[r, axis] * inv_res
            if f != f:
                return True
            if f < 0.0:
                f = 0.0
            if f > f_max[axis]:
                f = f_max[axis]
            index += int(f) * strides[axis]
        hit = steep_cells[index] and (among.size == 0 or among[r])
        out[r] = hit
        found |= hit
    return found


@njit(cache=True)
def cover_footprints(
    true_poses: np.ndarray, ids: np.ndarray, inv_res: float, footprint: np.ndarray,
    nx: int, ny: int, drivable: np.ndarray, covered: np.ndarray, new: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Mark the drivable cells of an ``nx x ny`` grid (flat, row ``x``) that the
    ``footprint`` cell offsets ``(F, 2)`` cover around the cell holding each robot
    ``ids``' true position; ``new[id]`` counts the cells that robot covered first
    (robots in the order of ``ids``, so a cell two reach counts for the earlier)."""
    for i in ids:
        fx = true_poses[i, 0] * inv_res
        fy = true_poses[i, 1] * inv_res
        if fx != fx or fy != fy:
            continue
        cx = math.floor(fx)
        cy = math.floor(fy)
        for j in range(footprint.shape[0]):
            x = cx + footprint[j, 0]
            y = cy + footprint[j, 1]
            if x < 0 or x >= nx or y < 0 or y >= ny:
                continue
            flat = x * ny + y
            if drivable[flat] and not covered[flat]:
                covered[flat] = True
                new[i] += 1


@njit(cache=True)
def fan_inputs(
    static: np.ndarray, extra: np.ndarray, pose: np.ndarray, fan_angles: np.ndarray,
    ref_state: np.ndarray, tolerance: np.ndarray, check: bool, index: np.ndarray,
    heading: np.ndarray, rel: np.ndarray,
) -> bool:  # pragma: no cover (compiled)
    """The inputs of :func:`fan_ranges` once the candidate lists are known valid.

    The scene's state is the static circles' centres ``(S, 2)``, then the moving
    ones' ``extra`` ``(E, 2)``, then the fans' poses ``(F, 3)``, flat; with ``check``
    it must lie within ``tolerance`` of ``ref_state`` (the state the lists were made
    for; NaN never does), else nothing is written and False comes back. Writes
    each fan's ray ``heading`` ``(F, R)`` (pose heading plus ``fan_angles``) and
    ``rel`` ``(F, K, 2)``: candidate circle minus fan position, the candidates being
    ``index`` ``(F, K)`` into the circles (static first), or every circle when
    ``index`` is empty.
    """
    n_static = static.shape[0]
    n_fans = pose.shape[0]
    if check:
        at = 0
        for i in range(n_static):
            for d in range(2):
                if not abs(static[i, d] - ref_state[at]) <= tolerance[at]:
                    return False
                at += 1
        for i in range(extra.shape[0]):
            for d in range(2):
                if not abs(extra[i, d] - ref_state[at]) <= tolerance[at]:
                    return False
                at += 1
        for i in range(n_fans):
            for d in range(3):
                if not abs(pose[i, d] - ref_state[at]) <= tolerance[at]:
                    return False
                at += 1
    for f in range(n_fans):
        for j in range(fan_angles.shape[1]):
            heading[f, j] = pose[f, 2] + fan_angles[f, j]
    every = index.size == 0 and rel.shape[1] > 0
    for f in range(n_fans):
        px = pose[f, 0]
        py = pose[f, 1]
        for k in range(rel.shape[1]):
            c = k if every else index[f, k]
            if c < n_static:
                cx = static[c, 0]
                cy = static[c, 1]
            else:
                cx = extra[c - n_static, 0]
                cy = extra[c - n_static, 1]
            rel[f, k, 0] = cx - px
            rel[f, k, 1] = cy - py
    return True


@njit(cache=True)
def noisy_ranges_into(out: np.ndarray, ranges: np.ndarray, std: float,
                      rmax: float) -> None:  # pragma: no cover (compiled)
    """``out`` (standard normals, the shape of ``ranges`` ``(n, beams)``) becomes
    ``ranges + std * out`` clipped to ``[0, rmax]``, exactly ``rmax`` where ``ranges >=
    rmax`` (NaN stays NaN): :func:`coop_loc_env.sensors._noisy_ranges` in one pass."""
    for a in range(ranges.shape[0]):
        for b in range(ranges.shape[1]):
            r = ranges[a, b]
            x = out[a, b] * std
            x += r
            if x < 0.0:
                x = 0.0
            if x > rmax:
                x = rmax
            if r >= rmax:
                x = rmax
            out[a, b] = x


@njit(cache=True)
def pack_observations(
    belief: np.ndarray, latched: np.ndarray, last_action: np.ndarray, belief_size: int,
    limit: float, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Rows ``[belief, zeros up to belief_size, latched, last_action]`` cast to ``out``'s
    float32 and clipped to ``[-limit, limit]`` (NaN stays NaN), as
    :meth:`coop_loc_env.observations.ObservationBuilder.build_all` lays them out."""
    lo = np.float32(-limit)
    hi = np.float32(limit)
    for r in range(out.shape[0]):
        c = 0
        for j in range(belief.shape[1]):
            out[r, c] = np.float32(belief[r, j])
            c += 1
        while c < belief_size:
            out[r, c] = np.float32(0.0)
            c += 1
        for j in range(latched.shape[1]):
            out[r, c] = np.float32(latched[r, j])
            c += 1
        for j in range(last_action.shape[1]):
            out[r, c] = np.float32(last_action[r, j])
            c += 1
        for j in range(c):
            x = out[r, j]
            if x < lo:
                x = lo
            if x > hi:
                x = hi
            out[r, j] = x


@njit(cache=True)
def pool_scans(
    ranges: np.ndarray, scale: np.ndarray, starts: np.ndarray, fired: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """Min-pool each scanning robot's row of ``ranges`` ``(n, beams)`` divided by its
    ``scale`` into ``out``'s ``len(starts)`` bins (``np.fmin.reduceat`` over ``starts``:
    NaN ignored, a bin of NaN only reads 1); rows where ``fired`` is False are kept."""
    n_bins = starts.size
    beams = ranges.shape[1]
    for r in range(ranges.shape[0]):
        if not fired[r]:
            continue
        for i in range(n_bins):
            s = starts[i]
            e = starts[i + 1] if i + 1 < n_bins else beams
            m = ranges[r, s] / scale[r]
            for j in range(s + 1, e):
                v = ranges[r, j] / scale[r]
                if v < m or m != m:  # fmin: the other one when one is NaN
                    m = v
            out[r, i] = 1.0 if m != m else m


@njit(cache=True)
def odometry_variance_into(
    odo: np.ndarray, slip_std: float, encoder_var: np.ndarray, scale: float, out: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """``out[i, t, k] = scale * (encoder_var[i] + (slip_std * odo[t, k, i])^2)`` for the
    ``(V, w)`` components ``i`` of odometry ``odo`` ``(T, k, 2)`` (the multiplication
    by ``scale`` only when it is not 1)."""
    n_sub, k, _ = odo.shape
    for i in range(2):
        for t in range(n_sub):
            for r in range(k):
                x = odo[t, r, i] * slip_std
                x *= x
                x += encoder_var[i]
                if scale != 1.0:
                    x *= scale
                out[i, t, r] = x


@njit(cache=True)
def near_pairs(
    xy: np.ndarray, robots: np.ndarray, centers: np.ndarray, radii: np.ndarray,
    reach: np.ndarray, n_static: int, pr: np.ndarray, pc: np.ndarray, d2v: np.ndarray,
    dxv: np.ndarray, dyv: np.ndarray, ratio: np.ndarray, inside: np.ndarray,
) -> int:  # pragma: no cover (compiled)
    """The (robot slot, circle) pairs of :meth:`FanCaster._cast_circles` in row-major order:
    circle within the robot's ``reach`` plus its radius, never the robot's own body
    (circle ``n_static + robots[f]``). For each pair writes the slot and circle, the
    squared distance, the offset ``circle - robot`` and ``min(r / max(d, 1e-12), 1)``
    (the sine of the half-angle it covers) and whether the robot is inside it; returns
    the number of pairs."""
    m = 0
    for f in range(xy.shape[0]):
        own = n_static + robots[f]
        for c in range(centers.shape[0]):
            if c == own:
                continue
            dx = centers[c, 0] - xy[f, 0]
            dy = centers[c, 1] - xy[f, 1]
            d2 = dx * dx + dy * dy
            lim = reach[f] + radii[c]
            if not d2 < lim * lim:
                continue
            d = math.sqrt(d2)
            r = radii[c]
            q = r / (d if d > 1e-12 or d != d else 1e-12)
            pr[m] = f
            pc[m] = c
            d2v[m] = d2
            dxv[m] = dx
            dyv[m] = dy
            ratio[m] = q if q < 1.0 or q != q else 1.0
            inside[m] = d <= r
            m += 1
    return m


@njit(cache=True)
def _search(keys: np.ndarray, lo: int, hi: int, v: float,
            right: bool) -> int:  # pragma: no cover (compiled)
    """``np.searchsorted(keys, v, side)`` (``"right"`` if ``right``) on sorted finite
    ``keys`` whose answer is known to lie in ``[lo, hi]``; NaN sorts last (``hi``)."""
    if v != v:
        return hi
    while lo < hi:
        mid = (lo + hi) // 2
        if keys[mid] < v or (right and keys[mid] == v):
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def circle_ray_hits(
    pr: np.ndarray, pc: np.ndarray, d2v: np.ndarray, half: np.ndarray, angle: np.ndarray,
    robots: np.ndarray, heading: np.ndarray, key_stride: float, sorted_key: np.ndarray,
    segments: np.ndarray, order: np.ndarray, origins: np.ndarray, dirs: np.ndarray,
    centers: np.ndarray, radii: np.ndarray, dist: np.ndarray,
) -> None:  # pragma: no cover (compiled)
    """The hits of :meth:`FanCaster._cast_circles`: each pair's rays (binary searches over
    the rays sorted by robot and angle, the angular interval in up to three pieces) meet
    its circle; ``dist`` keeps the nearest (``np.minimum.at``, in numpy's order).

    ``half`` is the half-angle each pair covers (``pi`` from inside), ``angle`` the
    ``atan2`` of its offset, ``heading`` each slot's robot heading and ``segments``
    ``(slots, 2)`` where each slot's rays start and end in ``sorted_key``. A robot's
    keys lie in ``[base, base + 2 pi]``, the others' outside, so a search of its own
    segment gives numpy's answer for a key in that span; outside it, the interval
    holds none of the robot's rays either way (NaN bounds search every key).
    """
    m = pr.size
    lo_k = np.empty(3 * m)
    hi_k = np.empty(3 * m)
    base = np.empty(m)
    for i in range(m):
        b = (angle[i] - heading[pr[i]]) + _PI
        b %= _TWO_PI
        lo = b - half[i]
        hi = b + half[i]
        base[i] = robots[pr[i]] * key_stride
        lo_k[i] = lo if lo > 0.0 or lo != lo else 0.0
        hi_k[i] = hi if hi < _TWO_PI or hi != hi else _TWO_PI
        lo_k[m + i] = lo + _TWO_PI
        hi_k[m + i] = _TWO_PI
        lo_k[2 * m + i] = 0.0
        hi_k[2 * m + i] = hi - _TWO_PI
    for p in range(3 * m):
        i = p % m
        v_lo = base[i] + lo_k[p]
        v_hi = base[i] + hi_k[p]
        if v_lo > v_hi:  # no key is >= v_lo and <= v_hi: no ray
            continue
        a = segments[pr[i], 0]
        z = segments[pr[i], 1]
        if v_lo != v_lo or v_hi != v_hi:  # NaN sorts last: numpy's search of every key
            a = 0
            z = sorted_key.size
        start = _search(sorted_key, a, z, v_lo, False)
        stop = _search(sorted_key, a, z, v_hi, True)
        c_idx = pc[i]
        r = radii[c_idx]
        c = d2v[i] - r * r
        for s in range(start, stop):
            ray = order[s]
            fx = origins[ray, 0] - centers[c_idx, 0]
            fy = origins[ray, 1] - centers[c_idx, 1]
            b = fx * dirs[ray, 0] + fy * dirs[ray, 1]
            disc = b * b - c
            sq = math.sqrt(disc if disc > 0.0 or disc != disc else 0.0)
            t = (-b - sq) if c > 0 else (-b + sq)
            if disc < 0 or t < 0:
                t = np.inf
            cur = dist[ray]
            if not (cur <= t or cur != cur):  # np.minimum: NaN wins, else the smaller
                dist[ray] = t
