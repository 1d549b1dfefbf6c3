"""Vectorized ray casting against circles and segments (numpy, no Python loop per ray)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coop_loc_env._step_kernels import circle_ray_hits, fan_inputs, fan_ranges, near_pairs


@dataclass
class RayScene:
    """Static geometry for ray casting.

    ``circle_*`` and ``segment_*`` arrays describe obstacles; ``*_mask`` holds
    one boolean column per sensor channel (0 = laser, 1 = sonar, 2 = camera /
    line of sight) saying whether that channel sees the shape. ``bounds``,
    when given, adds the walls of the world box (rays start inside it).
    """

    circle_centers: np.ndarray  # (C, 2)
    circle_radii: np.ndarray  # (C,)
    circle_mask: np.ndarray  # (C, 3) bool
    seg_a: np.ndarray  # (S, 2)
    seg_b: np.ndarray  # (S, 2)
    seg_mask: np.ndarray  # (S, 3) bool
    bounds: tuple[float, float] | None = None  # world box [0, w] x [0, h]: walls seen by all


CHANNEL = {"laser": 0, "sonar": 1, "sight": 2}


def _circle_hits(
    origins: np.ndarray, dirs: np.ndarray, centers: np.ndarray, radii: np.ndarray
) -> np.ndarray:
    """``(R, C)`` distance along each ray to each circle's entry point (its exit point
    for a ray starting inside); NaN where the ray's line misses, negative behind it."""
    fx = origins[:, 0:1] - centers[:, 0]
    fy = origins[:, 1:2] - centers[:, 1]
    b = fx * dirs[:, 0:1] + fy * dirs[:, 1:2]
    disc = b * b - (fx * fx + fy * fy - radii * radii)
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)  # NaN where the line misses
    np.negative(b, out=b)
    t = b - sq
    np.add(b, sq, out=t, where=t < 0)  # origin inside the circle: exit point
    return t


def ray_circles(
    origins: np.ndarray, dirs: np.ndarray, centers: np.ndarray, radii: np.ndarray
) -> np.ndarray:
    """Distance along each ray to each circle, ``inf`` on a miss. Shape ``(R, C)``."""
    if len(centers) == 0:
        return np.full((len(origins), 0), np.inf)
    t = _circle_hits(origins, dirs, centers, radii)
    with np.errstate(invalid="ignore"):
        t[~(t >= 0)] = np.inf  # NaN (a miss) fails the test too
    return t


def circles_block(
    origins: np.ndarray, dirs: np.ndarray, centers: np.ndarray, radii: np.ndarray,
    reach: np.ndarray,
) -> np.ndarray:
    """Whether any circle cuts each ray closer than ``reach`` (``(R,)`` bool): the same
    as ``ray_circles(...).min(1) < reach`` without the table of ``inf``."""
    if len(centers) == 0:
        return np.zeros(len(origins), dtype=bool)
    t = _circle_hits(origins, dirs, centers, radii)
    with np.errstate(invalid="ignore"):  # NaN (a miss) fails both tests
        return np.logical_or.reduce((t >= 0) & (t < reach[:, None]), axis=1)


def ray_segments(
    origins: np.ndarray, dirs: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray
) -> np.ndarray:
    """Distance along each ray to each segment, ``inf`` on a miss. Shape ``(R, S)``."""
    if len(seg_a) == 0:
        return np.full((len(origins), 0), np.inf)
    ex = seg_b[:, 0] - seg_a[:, 0]
    ey = seg_b[:, 1] - seg_a[:, 1]
    wx = seg_a[:, 0] - origins[:, 0:1]
    wy = seg_a[:, 1] - origins[:, 1:2]
    dx, dy = dirs[:, 0:1], dirs[:, 1:2]
    denom = dx * ey - dy * ex
    parallel = np.abs(denom) < 1e-12
    denom = np.where(parallel, 1.0, denom)
    t = (wx * ey - wy * ex) / denom
    u = (wx * dy - wy * dx) / denom
    t[parallel | (t < 0) | (u < 0) | (u > 1)] = np.inf
    return t


def cast(
    scene: RayScene,
    origins: np.ndarray,
    dirs: np.ndarray,
    channel: int,
    extra_centers: np.ndarray | None = None,
    extra_radii: np.ndarray | None = None,
    extra_exclude: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of each ray on the scene plus optional extra circles (robots).

    Args:
        origins, dirs: ``(R, 2)`` ray origins and unit directions.
        channel: which sensor channel's visibility mask applies.
        extra_centers, extra_radii: dynamic circles (e.g. robots), ``(E, 2)``, ``(E,)``.
        extra_exclude: ``(R,)`` index of the extra circle each ray ignores
            (its own robot), or -1.

    Returns:
        ``(distance (R,), hit_extra (R,))``: the hit distance (``inf`` on a miss)
        and the index of the extra circle hit, or -1 when the nearest hit is static.
    """
    cm = scene.circle_mask[:, channel]
    centers, radii = scene.circle_centers[cm], scene.circle_radii[cm]
    n_static = len(radii)
    if extra_centers is not None and len(extra_centers):
        centers = np.concatenate([centers, extra_centers])
        radii = np.concatenate([radii, extra_radii])
    if len(radii):
        d = ray_circles(origins, dirs, centers, radii)
        if extra_exclude is not None and len(radii) > n_static:
            rows = np.nonzero(extra_exclude >= 0)[0]
            d[rows, n_static + extra_exclude[rows]] = np.inf
        j = d.argmin(1)
        best = d[np.arange(len(d)), j]
        hit_extra = np.where((j >= n_static) & np.isfinite(best), j - n_static, -1)
    else:
        best = np.full(len(origins), np.inf)
        hit_extra = np.full(len(origins), -1)
    sm = scene.seg_mask[:, channel]
    if sm.any():
        seg = ray_segments(origins, dirs, scene.seg_a[sm], scene.seg_b[sm]).min(1)
        hit_extra = np.where(seg < best, -1, hit_extra)
        best = np.minimum(best, seg)
    if scene.bounds is not None:
        wall = ray_box(origins, dirs, scene.bounds)
        hit_extra = np.where(wall < best, -1, hit_extra)
        best = np.minimum(best, wall)
    return best, hit_extra


class FanCaster:
    """Casts fixed fans of rays from moving robots, visiting only the circles each ray can hit.

    Each ray belongs to a robot and has a fixed angle in that robot's frame.
    Per cast, every (robot, circle) pair within range gives the bearing
    interval the circle covers; the rays inside it are found by a binary
    search over the robot's rays sorted by angle, so the work grows with the
    number of actual ray-circle crossings rather than rays x circles.
    Segments are tested against every ray of the channel. Small teams test
    rays against circles in one table; with equal fans and no segments, each
    robot's rows hold only its candidate circles, listed anew when the robots
    have moved or turned enough (``move_skin``, ``turn_skin``).

    Args:
        scene: the static geometry.
        channel: sensor channel (``CHANNEL``) whose visibility mask applies.
        ray_robot: ``(R,)`` robot index of each ray.
        ray_angle: ``(R,)`` ray angle in the robot frame (rad).
        max_range: ``(R,)`` range beyond which hits are not needed.
    """

    def __init__(
        self,
        scene: RayScene,
        channel: int,
        ray_robot: np.ndarray,
        ray_angle: np.ndarray,
        max_range: np.ndarray,
    ) -> None:
        cm = scene.circle_mask[:, channel]
        self.centers = scene.circle_centers[cm]
        self.radii = scene.circle_radii[cm]
        sm = scene.seg_mask[:, channel]
        self.seg_a, self.seg_b = scene.seg_a[sm], scene.seg_b[sm]
        self.bounds = scene.bounds
        self._bounds_xy = None if scene.bounds is None else np.array(scene.bounds, dtype=float)
        self.ray_robot = np.asarray(ray_robot, dtype=np.intp)
        self.ray_angle = np.asarray(ray_angle, dtype=float)
        self.robots, self.ray_slot = np.unique(self.ray_robot, return_inverse=True)
        self.dense_limit = 20_000  # rays x circles up to which testing all pairs is cheaper
        counts = np.bincount(self.ray_slot)
        robot_major = bool(np.all(np.diff(self.ray_slot) >= 0))
        same_fan = len(counts) > 0 and bool(np.all(counts == counts[0]))
        self.fans = (len(counts), int(counts[0]), 2) if robot_major and same_fan else None
        # Fan angles per robot (rows), and the team size for which the fans' robots are
        # 0 .. n - 1 in order (then poses are sliced, not gathered).
        self._fan_angles = (
            self.ray_angle.reshape(self.fans[:2]) if self.fans is not None else None
        )
        all_rows = np.array_equal(self.robots, np.arange(len(self.robots)))
        self._robots_are_all = len(self.robots) if all_rows else -1
        self._own_key: tuple[int, int] | None = None
        self._extra_key: bytes | None = None  # the extra radii (as bytes) of the cached table
        self._radii_all = self.radii
        self._radii_sq = self.radii * self.radii
        self._own = (np.zeros(0, np.intp), np.zeros(0, np.intp))
        wrapped = (self.ray_angle + np.pi) % (2 * np.pi)  # in [0, 2 pi)
        key = self.ray_robot * _KEY_STRIDE + wrapped
        self.order = np.argsort(key, kind="stable")
        self.sorted_key = key[self.order]
        # Where each robot's rays start and end in sorted_key (keys base + [0, 2 pi]).
        base = self.robots * _KEY_STRIDE
        self._segments = np.stack([np.searchsorted(self.sorted_key, base - 0.5),
                                   np.searchsorted(self.sorted_key, base + 7.5)], 1)
        reach = np.zeros(self.ray_robot.max() + 1 if len(self.ray_robot) else 0)
        np.maximum.at(reach, self.ray_robot, np.asarray(max_range, dtype=float))
        self.reach = reach[self.robots]
        # Candidate circles of equal fans (:meth:`_near_circles`): kept while no robot or
        # extra circle has moved more than ``move_skin`` along x or y and no robot has
        # turned more than ``turn_skin`` (rad) since they were listed (new values apply
        # from the next lists); used while the longest list has at most ``cull_fraction``
        # of the circles.
        self.move_skin = 0.5
        self.turn_skin = 0.6
        self.cull_fraction = 0.75
        self._near: tuple | None = None
        self._near_key: tuple = (None,)  # what _near_const was made for
        self._near_const: tuple = ()
        if self._fan_angles is not None:
            lo, hi = self._fan_angles.min(1), self._fan_angles.max(1)
            self._fan_mid, self._fan_half = 0.5 * (lo + hi), 0.5 * (hi - lo)
            self._box_wh = np.zeros(0) if self._bounds_xy is None else self._bounds_xy

    def cast(
        self,
        poses: np.ndarray,
        extra_centers: np.ndarray | None = None,
        extra_radii: np.ndarray | None = None,
    ) -> np.ndarray:
        """Distance along each ray (``inf`` on a miss), in the constructor's ray order.

        A hit farther than the robot's longest ``max_range`` may be skipped (a farther
        hit, a wall or ``inf`` comes back instead); nearer hits are exact.

        Args:
            poses: ``(n, 3)`` robot poses (rows indexed by ``ray_robot``).
            extra_centers, extra_radii: moving circles (the robots) ``(E, 2)``, ``(E,)``;
                the circle with a ray's own robot index is skipped. The combined
                radii are reused while ``extra_radii`` holds the same values.
        """
        rays = len(self.ray_robot)
        centers, radii, n_static = self.centers, self.radii, len(self.radii)
        extra = extra_centers is not None and len(extra_centers) > 0
        if extra:
            radii = self._all_radii(extra_radii)
        dense = len(radii) * rays <= self.dense_limit
        if dense and self.fans is not None and not len(self.seg_a):
            return self._cast_fans(poses, extra_centers if extra else None, radii, n_static)
        if extra:
            centers = np.concatenate([centers, extra_centers])
        dist = np.full(rays, np.inf)
        if rays == 0:
            return dist
        heading = poses[self.ray_robot, 2] + self.ray_angle
        dirs = np.exp(1j * heading).view(np.float64).reshape(rays, 2)  # (cos, sin)
        origins = poses[self.ray_robot, :2]
        if dense:
            self._dense_circles(poses, centers, radii, n_static, dirs, origins, dist)
        else:
            self._cast_circles(poses, centers, radii, n_static, dirs, origins, dist)
        if len(self.seg_a):
            np.minimum(dist, ray_segments(origins, dirs, self.seg_a, self.seg_b).min(1), out=dist)
        if self._bounds_xy is not None:
            ray_box(origins, dirs, self._bounds_xy, out=dist)
        return dist

    def _cast_fans(
        self,
        poses: np.ndarray,
        extra_centers: np.ndarray | None,
        radii: np.ndarray,
        n_static: int,
    ) -> np.ndarray:
        """:meth:`cast` for equal fans, rays robot-major, circles and box only (small teams).

        Each robot's rays meet its candidate circles (:meth:`_near_circles`; every
        circle when the lists would not shrink the table much) in one
        ``(circles, robots, rays)`` table (see :meth:`_dense_circles` for the algebra);
        the nearest positive ``1 / t`` is reduced over the circles axis, with ``0``
        (no hit) as the starting value. A padded slot of a candidate list, like a
        robot's own body, has ``q = inf``, so none of its rays hits it.
        """
        n_fans, n_rays, _ = self.fans
        rows = slice(None) if self._robots_are_all == len(poses) else self.robots
        pose = poses[rows]
        extra = _NO_CENTERS if extra_centers is None else extra_centers
        near = self._near
        check = not (near is None or near[0] is not radii
                     or len(near[1]) != 2 * len(radii) + pose.size)
        heading = np.empty((n_fans, n_rays))
        if check:  # the lists still hold: headings and candidates' offsets in one pass
            rel = np.empty((n_fans, len(radii) if near[3] is None else near[3].shape[1], 2))
            check = fan_inputs(self.centers, extra, pose, self._fan_angles, near[1], near[2],
                               True, _NO_INDEX if near[3] is None else near[3], heading, rel)
        if not check:  # new candidate lists (or NaN poses), then the same pass unchecked
            parts = [self.centers.ravel(), pose.ravel()]
            if extra_centers is not None:
                parts.insert(1, extra_centers.ravel())
            state = np.concatenate(parts)  # the circles' centres, then the fans' poses
            centers = state[: 2 * len(radii)].reshape(-1, 2)
            near = self._near = self._near_circles(state, pose, centers, radii, n_static)
            rel = np.empty((n_fans, len(radii) if near[3] is None else near[3].shape[1], 2))
            fan_inputs(self.centers, extra, pose, self._fan_angles, near[1], near[2], False,
                       _NO_INDEX if near[3] is None else near[3], heading, rel)
        dirs = np.empty((2, n_fans, n_rays))  # (cos, sin) planes
        np.cos(heading, out=dirs[0])
        np.sin(heading, out=dirs[1])
        # The table is laid out (circles, robots, rays), so that the reduction over the
        # circles runs over whole planes.
        b = np.empty((rel.shape[1], n_fans, n_rays))
        np.matmul(rel, dirs.transpose(1, 0, 2), out=b.transpose(1, 0, 2))
        dist = np.empty((n_fans, n_rays))
        fan_ranges(b, rel, near[4], dirs, pose, self._box_wh, dist)
        return dist.reshape(-1)

    def _near_circles(
        self,
        state: np.ndarray,
        pose: np.ndarray,
        centers: np.ndarray,
        radii: np.ndarray,
        n_static: int,
    ) -> tuple:
        """Per robot, the circles its fan can hit within its reach while the scene moves
        little (a Verlet list), for :meth:`_cast_fans`.

        Until a new list, robot and circle close in by at most ``g = 2 sqrt(2)
        move_skin`` and the fan turns by at most ``turn_skin``. A circle is listed when,
        grown by ``g``, it lies within ``reach + r + g`` and reaches into the front
        half-plane of one of the fan's two side directions (below); otherwise
        no ray can hit it within reach (nor in front at all). The lists are padded to
        the longest with slots of ``r^2 = -inf``.

        Returns:
            ``(radii, state, tolerance, index, r2)``: the radii and ``state`` (centres
            then poses, flat) they were made for, the change of each ``state`` entry up
            to which they stay valid, and the ``(robots, K)`` circle index and squared
            radius of each slot (``-inf`` for padding and a robot's own body); ``index``
            is None when the lists would not shrink the table (``r2`` then covers every
            circle).
        """
        n_fans, n_circles = len(pose), len(radii)
        key = (len(state), self.move_skin, self.turn_skin)
        if self._near_key[0] is not radii or self._near_key[1:] != key:
            tolerance = np.full(len(state), self.move_skin)
            tolerance[: 2 * n_static] = 0.0  # the scene's circles do not move
            tolerance[2 * n_circles + 2 :: 3] = self.turn_skin  # headings
            grown = radii + 2 * np.sqrt(2) * self.move_skin + 1e-9
            # Two directions per fan whose front half-planes together hold every ray of
            # the fan turned by up to turn_skin either way: the fan's middle turned by
            # +-(w - pi / 2), w its half-width plus turn_skin clipped to [pi / 2, pi]
            # (at pi they are opposite and nothing is behind).
            w = np.minimum(self._fan_half + self.turn_skin, np.pi) - np.pi / 2
            sides = self._fan_mid[:, None] + np.maximum(w, 0.0)[:, None] * _SIDES
            self._near_key = (radii, *key)
            self._near_const = (tolerance, grown, (self.reach[:, None] + grown) ** 2, sides)
        tolerance, grown, reach2, sides = self._near_const
        rel = centers[None] - pose[:, None, :2]  # (robots, circles, 2)
        keep = np.einsum("rck,rck->rc", rel, rel) <= reach2
        sides = np.exp(1j * (pose[:, 2:3] + sides)).view(np.float64).reshape(n_fans, 2, 2)
        ahead = np.matmul(sides, rel.transpose(0, 2, 1))  # (robots, 2, circles)
        keep &= np.maximum(ahead[:, 0], ahead[:, 1]) >= -grown
        own = self._own_circles(n_circles, n_static)
        keep[own[0], own[1]] = False
        count = keep.sum(1)
        longest = int(count.max()) if n_fans else 0
        if longest > self.cull_fraction * n_circles:
            r2 = np.tile(self._squared(radii), (n_fans, 1))
            r2[own[0], own[1]] = -np.inf
            return radii, state, tolerance, None, r2
        index = np.argsort(~keep, axis=1, kind="stable")[:, :longest]
        r2 = self._squared(radii)[index]
        r2[np.arange(longest) >= count[:, None]] = -np.inf
        return radii, state, tolerance, index, r2

    def _dense_circles(self, poses, centers, radii, n_static, dirs, origins, dist) -> None:
        """Every ray against every circle, in few array operations (small teams).

        Along a ray ``o + t u`` a circle ``(c, r)`` is hit at ``t = b - sqrt(b^2 - q)``
        with ``b = u.(c - o)`` and ``q = |c - o|^2 - r^2``; the nearest hit in front is
        the largest positive ``1 / t`` (NaN where the ray misses, ignored by ``fmax``).
        Rays start outside every circle but their own robot's, which is skipped.
        """
        rel = centers.T[None] - poses[self.robots, :2, None]  # (robots, 2, circles)
        q = rel[:, 0] * rel[:, 0]  # |c - o|^2 without a reduction
        q += rel[:, 1] * rel[:, 1]
        q -= self._squared(radii)
        if len(radii) > n_static:
            own = self._own_circles(len(radii), n_static)
            q[own[0], own[1]] = np.inf
        if self.fans is not None:  # every robot has the same fan, rays robot-major
            b = np.matmul(dirs.reshape(self.fans), rel)  # (robots, rays, circles)
            q = q[:, None, :]
        else:
            b = np.einsum("rk,rkc->rc", dirs, rel[self.ray_slot])
            q = q[self.ray_slot]
        with np.errstate(invalid="ignore"):
            disc = b * b
            disc -= q
            np.sqrt(disc, out=disc)
            b -= disc
            np.reciprocal(b, out=b)
            inv = np.fmax.reduce(b, axis=-1).reshape(-1)
        np.divide(1.0, inv, out=dist, where=inv > 0)  # misses keep inf

    def _all_radii(self, extra_radii: np.ndarray) -> np.ndarray:
        """Static radii followed by ``extra_radii`` (reused while the same values repeat)."""
        key = extra_radii.tobytes()
        if key != self._extra_key:
            radii = np.concatenate([self.radii, extra_radii])
            self._extra_key, self._radii_all = key, radii
            self._radii_sq = radii * radii
        return self._radii_all

    def _squared(self, radii: np.ndarray) -> np.ndarray:
        """``radii * radii`` (the cached square for the combined radii)."""
        return self._radii_sq if radii is self._radii_all else radii * radii

    def _own_circles(self, n_circles: int, n_static: int) -> tuple[np.ndarray, np.ndarray]:
        """(row, column) in the (robots, circles) table of each robot's own body."""
        key = (n_circles, n_static)
        if self._own_key != key:
            rows, extra = np.nonzero(self.robots[:, None] == np.arange(n_circles - n_static))
            self._own = (rows, n_static + extra)
            self._own_key = key
        return self._own

    def _cast_circles(self, poses, centers, radii, n_static, dirs, origins, dist) -> None:
        """Rays against the circles near their robot: each (robot, circle) pair's angular
        interval picks its rays from the sorted keys (two compiled passes around numpy's
        arcsine and arctangent)."""
        rob = self.robots
        xy = poses[rob, :2]
        size = len(rob) * len(radii)
        pr, pc = np.empty(size, dtype=np.intp), np.empty(size, dtype=np.intp)
        d2v, dxv, dyv, ratio = np.empty(size), np.empty(size), np.empty(size), np.empty(size)
        inside = np.empty(size, dtype=bool)
        m = near_pairs(xy, rob, centers, radii, self.reach, n_static, pr, pc, d2v, dxv, dyv,
                       ratio, inside)
        if m == 0:
            return
        half = np.arcsin(ratio[:m])
        half[inside[:m]] = np.pi  # inside the circle: every ray exits through it
        angle = np.arctan2(dyv[:m], dxv[:m])
        circle_ray_hits(pr[:m], pc[:m], d2v[:m], half, angle, rob, poses[rob, 2], _KEY_STRIDE,
                        self.sorted_key, self._segments, self.order, origins, dirs, centers,
                        radii, dist)


_KEY_STRIDE = 8.0  # > 2 pi: separates robots in the sorted ray keys
_NO_CENTERS = np.zeros((0, 2))  # no moving circles (fan_inputs)
_NO_INDEX = np.zeros((0, 0), dtype=np.intp)  # every circle a candidate (fan_inputs)
_SIDES = np.array([1.0, -1.0])  # the two sides of a fan


def ray_box(
    origins: np.ndarray,
    dirs: np.ndarray,
    size: tuple[float, float] | np.ndarray,
    out: np.ndarray | None = None,
    axis: int = -1,
) -> np.ndarray:
    """Distance from points inside ``[0, w] x [0, h]`` along ``dirs`` to the box's walls.

    ``dirs`` holds the (x, y) components along ``axis``: shape ``(..., 2)`` by default,
    or ``(2, ...)`` with ``axis=0`` (then ``size`` and ``origins`` must broadcast that
    way too, e.g. ``size`` as ``(2, 1, 1)``); ``origins`` broadcasts against it. The
    result has ``dirs``' shape without that axis. With ``out``, the element-wise minimum
    of ``out`` and those distances is written into ``out`` (per axis, without a
    reduction) and returned.
    """
    with np.errstate(divide="ignore"):
        return _box_walls(origins, dirs, size, out, axis)


def _box_walls(
    origins: np.ndarray,
    dirs: np.ndarray,
    size: tuple[float, float] | np.ndarray,
    out: np.ndarray | None,
    axis: int,
) -> np.ndarray:
    """:func:`ray_box` without its ``errstate`` (a zero direction component warns)."""
    wall = np.where(dirs > 0, size, 0.0)
    wall -= origins
    wall /= dirs
    np.abs(wall, out=wall)
    if out is None:
        return wall.min(axis)
    x, y = (wall[0], wall[1]) if axis == 0 else (wall[..., 0], wall[..., 1])
    np.minimum(out, x, out=out)
    return np.minimum(out, y, out=out)
