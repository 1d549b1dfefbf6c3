"""Compiled loops (numba, cached on disk) for the main mode of a particle set and the
symmetric copies the MCL backend keeps of it.

They return exactly what the numpy code of :mod:`estimators.mcl.detection_consistency`
and :mod:`estimators.mcl.map_symmetry` returns, or say that they cannot tell (``ok``
False) and the caller runs that code: sums are formed in numpy's order where a result
depends on their rounding (:func:`pairwise_sum`), and where numpy's order cannot be
repeated (a sort, a BLAS dot) a decision is taken here only when it lies well clear of
what any order of rounding could change (``SAFE``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["copy_masks", "disc_weight_bound", "lightest_outside", "mode_mask", "pairwise_sum",
           "topped_up_weights", "turned_free", "uniform_centre", "weighted_median"]

SAFE = 1e-9  # relative margin: far above the rounding of a few thousand float64 terms


@njit(cache=True)
def _block(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover (compiled)
    """numpy's pairwise sum of ``a[lo:lo + n]`` for ``n <= 128``: eight running sums."""
    if n < 8:
        res = -0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    m = n - n % 8
    while i < m:
        j = lo + i
        r0 += a[j]
        r1 += a[j + 1]
        r2 += a[j + 2]
        r3 += a[j + 3]
        r4 += a[j + 4]
        r5 += a[j + 5]
        r6 += a[j + 6]
        r7 += a[j + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def _pairwise(a: np.ndarray, lo: int, n: int) -> float:  # pragma: no cover (compiled)
    """numpy's pairwise sum of ``a[lo:lo + n]``: blocks of at most 128, halves (cut at a
    multiple of 8) added left + right; the recursion unrolled on a small stack."""
    if n <= 128:
        return _block(a, lo, n)
    los = np.empty(64, dtype=np.int64)
    ns = np.empty(64, dtype=np.int64)
    lefts = np.empty(64)
    right = np.zeros(64, dtype=np.bool_)  # the frame's left half is summed
    top = 0
    los[0], ns[0], right[0] = lo, n, False
    while True:
        m = ns[top]
        if m > 128:
            half = m // 2
            half -= half % 8
            top += 1
            los[top], ns[top], right[top] = los[top - 1], half, False
            continue
        val = _block(a, los[top], m)
        top -= 1
        while top >= 0 and right[top]:
            val = lefts[top] + val
            top -= 1
        if top < 0:
            return val
        lefts[top] = val
        right[top] = True
        half = ns[top] // 2
        half -= half % 8
        top += 1
        los[top], ns[top], right[top] = los[top - 1] + half, ns[top - 1] - half, False


@njit(cache=True)
def pairwise_sum(a: np.ndarray) -> float:  # pragma: no cover (compiled)
    """``a.sum()`` of a contiguous float64 array, bit for bit (numpy's pairwise order)."""
    return _pairwise(a, 0, a.size)


@njit(cache=True)
def weighted_median(x: np.ndarray, w: np.ndarray) -> tuple[float, bool]:  # pragma: no cover
    """The weighted median of ``x`` under weights ``w >= 0`` (positive sum) as
    ``detection_consistency._weighted_median`` finds it (the first value in sorted order
    whose cumulative weight reaches half the total), by selection instead of a sort.

    ``ok`` is False (the value is then meaningless) when half the weight lies within
    ``SAFE`` of the cumulative weight at the crossing, where the sorted running sum's
    rounding decides, or when ``x`` holds NaN or ``w`` a negative or NaN weight.
    """
    n = x.size
    xs = x.copy()
    ws = w.copy()
    total = 0.0
    for i in range(n):
        if xs[i] != xs[i] or not ws[i] >= 0.0:
            return 0.0, False  # NaN, or a negative weight: the sort's answer holds
        total += ws[i]
    if not 0.0 < total < np.inf:
        return 0.0, False
    half = 0.5 * total
    tol = SAFE * total
    lo, hi = 0, n
    below = 0.0
    while hi > lo:
        a, m, b = xs[lo], xs[(lo + hi) // 2], xs[hi - 1]
        pivot = max(min(a, m), min(max(a, m), b))  # median of three
        # three-way partition of [lo, hi): < pivot, == pivot, > pivot
        lt, i, gt = lo, lo, hi
        while i < gt:
            v = xs[i]
            if v < pivot:
                xs[i], xs[lt] = xs[lt], v
                ws[i], ws[lt] = ws[lt], ws[i]
                lt += 1
                i += 1
            elif v > pivot:
                gt -= 1
                xs[i], xs[gt] = xs[gt], v
                ws[i], ws[gt] = ws[gt], ws[i]
            else:
                i += 1
        wl = 0.0
        for j in range(lo, lt):
            wl += ws[j]
        we = 0.0
        for j in range(lt, gt):
            we += ws[j]
        if below + wl >= half:
            hi = lt
        elif below + wl + we >= half:
            ok = below + wl < half - tol and below + wl + we >= half + tol
            return pivot, ok
        else:
            below += wl + we
            lo = gt
    return 0.0, False


@njit(cache=True)
def mode_mask(state: np.ndarray, ox: float, oy: float, w: np.ndarray, radius: float
              ) -> tuple[np.ndarray, float, bool]:  # pragma: no cover (compiled)
    """The mask of :func:`~estimators.mcl.detection_consistency.main_mode` for the world
    positions of a particle set (``state`` ``(3, n)`` float32 from the origin ``ox, oy``,
    as :class:`~estimators.mcl.team.ParticleSet` holds them) under weights ``w`` (positive
    sum), and ``w[mask].sum()``, bit for bit; ``ok`` False where that cannot be vouched
    for here (see the module docstring)."""
    n = w.size
    x = np.empty(n)
    y = np.empty(n)
    for i in range(n):
        x[i] = np.float64(state[0, i]) + ox
        y[i] = np.float64(state[1, i]) + oy
    mask = np.zeros(n, dtype=np.bool_)
    s = pairwise_sum(w)
    if not s > 0.0:
        return mask, 0.0, False
    wn = w / s
    mx = 0.0
    my = 0.0
    for i in range(n):
        mx += wn[i] * x[i]
        my += wn[i] * y[i]
    spread = 0.0
    for i in range(n):
        dx = x[i] - mx
        dy = y[i] - my
        spread += wn[i] * (dx * dx + dy * dy)
    lim = (0.25 * radius) ** 2
    if abs(spread - lim) <= SAFE * (lim + spread) + 1e-300 or spread != spread:
        return mask, 0.0, False
    if spread <= lim:
        cx, cy = mx, my
        exact = False
    else:
        cx, ok = weighted_median(x, wn)
        if not ok:
            return mask, 0.0, False
        cy, ok = weighted_median(y, wn)
        if not ok:
            return mask, 0.0, False
        exact = True
    r2 = radius * radius
    margin = SAFE * (r2 + 1.0)
    count = 0
    for i in range(n):
        dx = x[i] - cx
        dy = y[i] - cy
        d2 = dx * dx + dy * dy
        if not exact and abs(d2 - r2) <= margin:
            return mask, 0.0, False  # the mean's rounding could move this particle
        if d2 <= r2:
            mask[i] = True
            count += 1
    inside = np.empty(count)
    k = 0
    for i in range(n):
        if mask[i]:
            inside[k] = w[i]
            k += 1
    return mask, pairwise_sum(inside), True


@njit(cache=True)
def turned_free(poses: np.ndarray, cx: float, cy: float, angle: float, c: float, s: float,
                gx: float, gy: float, res: float, occupied: np.ndarray
                ) -> np.ndarray:  # pragma: no cover (compiled)
    """``symmetric_copies(poses, symmetry)`` restricted to the grid's free cells
    (``grid.is_free``), bit for bit: ``c, s`` are the cosine and sine of ``angle``, ``gx,
    gy`` the grid's origin and ``res`` its resolution."""
    n = poses.shape[0]
    ny, nx = occupied.shape
    out = np.empty((n, 3))
    two_pi = 2.0 * math.pi
    below_pi = np.nextafter(math.pi, 0.0)
    k = 0
    for i in range(n):
        dx = poses[i, 0] - cx
        dy = poses[i, 1] - cy
        px = cx + c * dx - s * dy
        py = cy + s * dx + c * dy
        ix = math.floor((px - gx) / res)
        iy = math.floor((py - gy) / res)
        if not (0 <= ix < nx and 0 <= iy < ny) or occupied[int(iy), int(ix)]:
            continue
        h = (poses[i, 2] + angle + math.pi) % two_pi - math.pi
        out[k, 0] = px
        out[k, 1] = py
        out[k, 2] = min(h, below_pi)
        k += 1
    return out[:k]


@njit(cache=True)
def uniform_centre(claimed: np.ndarray, radius: float
                   ) -> tuple[float, float, bool, bool]:  # pragma: no cover (compiled)
    """The centre :func:`~estimators.mcl.detection_consistency.main_mode` finds for poses
    ``claimed`` ``(M, 3)`` under equal weights: ``(cx, cy, exact, ok)``. ``exact``: the
    centre is a coordinate median, bit for bit (equal weights make the sorted running
    sum a function of ``M`` alone, repeated here); otherwise it is the mean up to
    rounding (a mask drawn about it needs a margin). ``ok`` False: the choice between
    mean and median lies within rounding of the threshold."""
    m = claimed.shape[0]
    u0 = 1.0 / m
    full = np.full(m, u0)
    u = u0 / pairwise_sum(full)
    mx = 0.0
    my = 0.0
    for i in range(m):
        mx += u * claimed[i, 0]
        my += u * claimed[i, 1]
    spread = 0.0
    for i in range(m):
        dx = claimed[i, 0] - mx
        dy = claimed[i, 1] - my
        spread += u * (dx * dx + dy * dy)
    lim = (0.25 * radius) ** 2
    if abs(spread - lim) <= SAFE * (lim + spread) + 1e-300 or spread != spread:
        return 0.0, 0.0, False, False
    if spread <= lim:
        return mx, my, False, True
    # numpy's cumsum of m equal weights, and the first entry reaching half the last
    cum = np.empty(m)
    c = 0.0
    for j in range(m):
        c = u if j == 0 else c + u
        cum[j] = c
    half = 0.5 * cum[m - 1]
    j = 0
    while j < m - 1 and cum[j] < half:
        j += 1
    xs = np.partition(claimed[:, 0].copy(), j)
    ys = np.partition(claimed[:, 1].copy(), j)
    return xs[j], ys[j], True, True


@njit(cache=True)
def copy_masks(x: np.ndarray, y: np.ndarray, wn: np.ndarray, claimed: np.ndarray,
               cx: float, cy: float, exact: bool, radius: float
               ) -> tuple[np.ndarray, np.ndarray, float, bool]:  # pragma: no cover
    """``widen``'s masks about the centre ``cx, cy`` of the claimed poses: the particles
    ``x, y`` within ``radius`` (``here``) and the claims within it (``near``), and
    ``wn[here].sum()`` bit for bit; ``ok`` False when the centre is not ``exact`` and a
    point lies within its rounding of the radius."""
    r2 = radius * radius
    margin = 0.0 if exact else SAFE * (r2 + 1.0)
    n = x.size
    here = np.zeros(n, dtype=np.bool_)
    inside = np.empty(n)
    k = 0
    for i in range(n):
        dx = x[i] - cx
        dy = y[i] - cy
        d2 = dx * dx + dy * dy
        if margin > 0.0 and abs(d2 - r2) <= margin:
            return here, here, 0.0, False
        if d2 <= r2:
            here[i] = True
            inside[k] = wn[i]
            k += 1
    m = claimed.shape[0]
    near = np.zeros(m, dtype=np.bool_)
    for i in range(m):
        dx = claimed[i, 0] - cx
        dy = claimed[i, 1] - cy
        d2 = dx * dx + dy * dy
        if margin > 0.0 and abs(d2 - r2) <= margin:
            return here, near, 0.0, False
        near[i] = d2 <= r2
    return here, near, _pairwise(inside, 0, k), True


@njit(cache=True)
def lightest_outside(wn: np.ndarray, here: np.ndarray, k: int
                     ) -> np.ndarray:  # pragma: no cover (compiled)
    """``outside[np.argsort(wn[outside], kind="stable")[:k]]`` for ``outside`` the indices
    not ``here``: the ``k`` least weights outside, ties by index."""
    slots = np.empty(k, dtype=np.intp)
    vals = np.empty(k)
    filled = 0
    for i in range(wn.size):
        if here[i]:
            continue
        v = wn[i]
        if filled == k and v >= vals[k - 1]:
            continue  # not lighter than the k-th (a tie keeps the earlier index)
        j = filled if filled < k else k - 1
        while j > 0 and vals[j - 1] > v:
            vals[j] = vals[j - 1]
            slots[j] = slots[j - 1]
            j -= 1
        vals[j] = v
        slots[j] = i
        if filled < k:
            filled += 1
    return slots[:filled]


@njit(cache=True)
def topped_up_weights(wn: np.ndarray, here: np.ndarray, slots: np.ndarray, mass: float,
                      have: float) -> np.ndarray:  # pragma: no cover (compiled)
    """``widen``'s new weights, bit for bit: the particles outside ``here`` and not in
    ``slots`` scaled to ``1 - mass`` in all, each slot ``(mass - have) / k``, normalized."""
    n = wn.size
    keep = np.ones(n, dtype=np.bool_)
    for i in range(n):
        keep[i] = not here[i]
    for s in slots:
        keep[s] = False
    rest_w = np.empty(n)
    k = 0
    for i in range(n):
        if keep[i]:
            rest_w[k] = wn[i]
            k += 1
    rest = _pairwise(rest_w, 0, k)
    f = (1.0 - mass) / rest if rest > 0 else 0.0
    out = wn.copy()
    for i in range(n):
        if keep[i]:
            out[i] *= f
    each = (mass - have) / slots.size
    for s in slots:
        out[s] = each
    return out / pairwise_sum(out)


@njit(cache=True)
def disc_weight_bound(state: np.ndarray, ox: float, oy: float, w: np.ndarray,
                      radius: float) -> float:  # pragma: no cover (compiled)
    """An upper bound on the weight ``w`` of the particles (``state`` as in
    :func:`mode_mask`) within ``radius`` of any point: the most weight in 2 x 2 cells of a
    grid of cells a little over ``2 * radius`` (a disc of that diameter meets at most 2 x 2
    of them);
    ``inf`` when the particles span more than 4096 cells."""
    n = w.size
    if n == 0:
        return 0.0
    cell = 2.0 * radius * (1.0 + 1e-6)  # a disc spans 2 cells even where rounding bins
    x0 = np.float64(state[0, 0]) + ox
    y0 = np.float64(state[1, 0]) + oy
    x1, y1 = x0, y0
    for i in range(n):
        x = np.float64(state[0, i]) + ox
        y = np.float64(state[1, i]) + oy
        if not (x == x and y == y):
            return np.inf
        x0, x1 = min(x0, x), max(x1, x)
        y0, y1 = min(y0, y), max(y1, y)
    nx = int((x1 - x0) / cell) + 1
    ny = int((y1 - y0) / cell) + 1
    if nx * ny > 4096:
        return np.inf
    grid = np.zeros((ny + 1, nx + 1))
    for i in range(n):
        ix = min(int((np.float64(state[0, i]) + ox - x0) / cell), nx - 1)
        iy = min(int((np.float64(state[1, i]) + oy - y0) / cell), ny - 1)
        grid[iy, ix] += w[i]
    best = 0.0
    for iy in range(ny):
        for ix in range(nx):
            s = grid[iy, ix] + grid[iy, ix + 1] + grid[iy + 1, ix] + grid[iy + 1, ix + 1]
            best = max(best, s)
    return best
