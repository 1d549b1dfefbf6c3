"""The simulated world: static layout, terrain, and skid-steer robots on pymunk.

The layout (obstacles, canopy, terrain) comes from ``cfg.layout_seed`` so the
map is the same in every episode; the episode seed places the robots and
drives all noise. Robot motion follows Eq. 1 of the outdoor paper: the
commanded ``(V, w)`` with multiplicative slip noise sets each body's velocity
for every physics substep, and pymunk resolves collisions with obstacles,
objects of interest, the world boundary and other robots.
"""

from __future__ import annotations

import numpy as np
import pymunk
import pymunk.batch

from coop_loc_env.config import START_GAP, Obstacle, ScenarioConfig
from coop_loc_env.raycast import RayScene
from coop_loc_env.terrain import HeightField
from estimators.geometry import wrap_angle

ROBOT_COLLISION_TYPE = 1
_WALL_RADIUS = 0.05
_VELOCITIES = pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY
_POSE_FIELDS = pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE


def _count_contact(arbiter: pymunk.Arbiter, space: pymunk.Space, data: dict) -> None:
    """pymunk begin-callback: count a new contact for the robot(s) involved."""
    for shape in arbiter.shapes:
        index = getattr(shape, "robot_index", None)
        if index is not None:
            data["counts"][index] += 1


class Layout:
    """Static obstacles of a scenario, with canopy zones and ray-casting arrays."""

    def __init__(self, cfg: ScenarioConfig, terrain: HeightField, rng: np.random.Generator):
        obstacles = list(cfg.obstacles)
        obstacles += _scatter(cfg, terrain, rng, obstacles)
        self.obstacles: tuple[Obstacle, ...] = tuple(obstacles)
        trees = [o for o in obstacles if o.canopy_radius > 0]
        self.canopy_centers = np.array([o.center for o in trees], dtype=float).reshape(-1, 2)
        self.canopy_radii = np.array([o.canopy_radius for o in trees], dtype=float)
        self.ooi_centers = np.array(
            [o.center for o in obstacles if o.kind == "ooi"], dtype=float
        ).reshape(-1, 2)
        self.scene = _ray_scene(cfg, obstacles)
        self._polygons = [np.asarray(o.vertices, dtype=float) for o in obstacles
                          if o.shape == "polygon" and o.solid]

    def under_canopy(self, points: np.ndarray) -> np.ndarray:
        """Depth of each point under canopy in [0, 1] (0 = open sky)."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if len(self.canopy_radii) == 0:
            return np.zeros(len(points))
        # linalg.norm's sqrt(x^2 + y^2) and clip's max/min, without their wrappers.
        rel = points[:, None, :] - self.canopy_centers[None]
        rel *= rel
        d = np.sqrt(rel[..., 0] + rel[..., 1])
        depth = 1.0 - d / self.canopy_radii[None]
        deepest = np.maximum.reduce(depth, axis=1)
        np.maximum(deepest, 0.0, out=deepest)
        return np.minimum(deepest, 1.0, out=deepest)

    def clearance(self, points: np.ndarray) -> np.ndarray:
        """Distance from each point to the nearest solid obstacle surface."""
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        s = self.scene
        w, h = s.bounds
        best = np.minimum(points, (w, h) - points).min(1)  # the world's walls
        if len(s.circle_radii):
            d = np.linalg.norm(points[:, None] - s.circle_centers[None], axis=2) - s.circle_radii
            best = np.minimum(best, d.min(1))
        if len(s.seg_a):
            e = s.seg_b - s.seg_a
            t = np.einsum("psd,sd->ps", points[:, None] - s.seg_a[None], e) / np.maximum(
                np.einsum("sd,sd->s", e, e), 1e-12
            )
            proj = s.seg_a[None] + np.clip(t, 0, 1)[..., None] * e[None]
            best = np.minimum(best, np.linalg.norm(points[:, None] - proj, axis=2).min(1))
        for verts in self._polygons:  # inside a solid polygon: no clearance at all
            best[_inside_polygon(points, verts)] = 0.0
        return best


def _inside_polygon(points: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Even-odd test: which of ``points (k, 2)`` lie inside the polygon ``verts (V, 2)``."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = verts[:, 0], verts[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return ((crosses & (x < x_at)).sum(axis=1) % 2).astype(bool)


def _scatter(
    cfg: ScenarioConfig, terrain: HeightField, rng: np.random.Generator, fixed: list[Obstacle]
) -> list[Obstacle]:
    """Randomly place the scenario's trees, rocks and objects of interest."""
    w, h = cfg.world_size
    placed: list[tuple[float, float, float]] = [
        (*o.center, o.radius) for o in fixed if o.shape == "circle"
    ]
    out: list[Obstacle] = []
    plan = (
        [("tree", cfg.tree_radius)] * cfg.n_random_trees
        + [("rock", cfg.rock_radius)] * cfg.n_random_rocks
        + [("ooi", 0.3)] * cfg.n_random_ooi
    )
    for kind, radius in plan:
        for _ in range(200):
            x, y = rng.uniform(2.0, w - 2.0), rng.uniform(2.0, h - 2.0)
            if terrain.is_steep(np.array([[x, y]]))[0]:
                continue
            if cfg.start_region is not None:
                x0, y0, x1, y1 = cfg.start_region
                if x0 - 1 <= x <= x1 + 1 and y0 - 1 <= y <= y1 + 1:
                    continue
            if all(
                (x - px) ** 2 + (y - py) ** 2 > (radius + pr + 2.0) ** 2 for px, py, pr in placed
            ):
                break
        else:
            continue
        placed.append((x, y, radius))
        out.append(
            Obstacle(
                kind=kind,
                shape="circle",
                center=(float(x), float(y)),
                radius=radius,
                canopy_radius=cfg.canopy_radius if kind == "tree" else 0.0,
            )
        )
    return out


def _ray_scene(cfg: ScenarioConfig, obstacles: list[Obstacle]) -> RayScene:
    segs = []
    circles = []
    for o in obstacles:
        mask = ("laser" in o.visible_to, "sonar" in o.visible_to, True)
        if o.shape == "circle":
            circles.append((o.center, o.radius, mask))
        elif o.shape == "segment":
            segs.append((o.a, o.b, mask))
        else:
            v = o.vertices
            segs += [(v[i], v[(i + 1) % len(v)], mask) for i in range(len(v))]
    return RayScene(
        circle_centers=np.array([c[0] for c in circles], dtype=float).reshape(-1, 2),
        circle_radii=np.array([c[1] for c in circles], dtype=float),
        circle_mask=np.array([c[2] for c in circles], dtype=bool).reshape(-1, 3),
        seg_a=np.array([s[0] for s in segs], dtype=float).reshape(-1, 2),
        seg_b=np.array([s[1] for s in segs], dtype=float).reshape(-1, 2),
        seg_mask=np.array([s[2] for s in segs], dtype=bool).reshape(-1, 3),
        bounds=(float(cfg.world_size[0]), float(cfg.world_size[1])),
    )


class World:
    """Physics of one episode: robots on pymunk among the static layout.

    Args:
        cfg: the scenario.
    """

    def __init__(self, cfg: ScenarioConfig) -> None:
        self.cfg = cfg
        layout_rng = np.random.default_rng(cfg.layout_seed)
        self.terrain = HeightField(cfg, layout_rng)
        self.layout = Layout(cfg, self.terrain, layout_rng)
        n = cfg.n_robots
        specs = [cfg.robot_spec(i) for i in range(n)]
        self.max_speed = np.array([s.max_speed for s in specs])
        self.max_turn_rate = np.array([s.max_turn_rate for s in specs])
        self.poses = np.zeros((n, 3))
        self.space: pymunk.Space | None = None
        self.bodies: list[pymunk.Body] = []
        self.contacts = {"counts": np.zeros(n, dtype=int)}

    # ------------------------------------------------------------------ reset
    def reset(self, rng: np.random.Generator) -> None:
        """Build the pymunk space and place the robots (seeded by ``rng``)."""
        cfg = self.cfg
        space = pymunk.Space()
        space.iterations = 10
        # Robots are driven by velocity every substep: correct overlaps quickly and
        # allow little slop so a robot pushing into a rock stays at its surface.
        space.collision_bias = pow(1.0 - 0.9, 60)
        space.collision_slop = 0.005
        static = space.static_body
        w, h = cfg.world_size
        corners = [(0.0, 0.0), (w, 0.0), (w, h), (0.0, h)]
        for i in range(4):
            space.add(pymunk.Segment(static, corners[i], corners[(i + 1) % 4], _WALL_RADIUS))
        for o in self.layout.obstacles:
            if not o.solid:
                continue
            if o.shape == "circle":
                shape = pymunk.Circle(static, o.radius, o.center)
            elif o.shape == "segment":
                shape = pymunk.Segment(static, o.a, o.b, o.radius)
            else:
                shape = pymunk.Poly(static, list(o.vertices))
            space.add(shape)
        self.contacts["counts"][:] = 0
        space.on_collision(ROBOT_COLLISION_TYPE, None, begin=_count_contact, data=self.contacts)
        self.poses = self._start_poses(rng)
        self.bodies = []
        for i, (x, y, th) in enumerate(self.poses):
            body = pymunk.Body(1.0, float("inf"))
            body.position = (float(x), float(y))
            body.angle = float(th)
            shape = pymunk.Circle(body, cfg.robot_radius)
            shape.collision_type = ROBOT_COLLISION_TYPE
            shape.robot_index = i
            shape.friction = 0.0
            space.add(body, shape)
            self.bodies.append(body)
        self.space = space
        self._angles = self.poses[:, 2].copy()
        self._make_batch_buffers()

    def _make_batch_buffers(self) -> None:
        """Buffers for pymunk's batch API (rebuilt after unpickling: they hold C pointers).

        The velocity buffer has one row per body pymunk iterates (the robots
        first, in order, then the static body), per substep, plus a final
        all-zero row that stops the robots.
        """
        probe = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(self.space, _POSE_FIELDS, probe)
        n_bodies = len(probe.float_buf()) // (3 * 8)
        self._velocity_buffer = np.zeros((self.cfg.odometry_substeps + 1, n_bodies, 3))
        self._velocity_rows = []
        for row in self._velocity_buffer:
            self._velocity_rows.append(pymunk.batch.Buffer())
            self._velocity_rows[-1].set_float_buf(row)
        self._state_batch = pymunk.batch.Buffer()
        self._batch = _BatchCalls.make(self.space, self._velocity_rows, self._state_batch)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("_velocity_buffer", "_velocity_rows", "_state_batch", "_batch"):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if self.space is not None:
            self._make_batch_buffers()

    def _start_poses(self, rng: np.random.Generator) -> np.ndarray:
        cfg = self.cfg
        n = cfg.n_robots
        if cfg.start_poses is not None:
            return np.array(cfg.start_poses[:n], dtype=float)
        w, h = cfg.world_size
        x0, y0, x1, y1 = cfg.start_region or (1.0, 1.0, w - 1.0, h - 1.0)
        r = cfg.robot_radius
        poses = []
        for i in range(n):
            for _ in range(2000):
                p = np.array([rng.uniform(x0 + r, x1 - r), rng.uniform(y0 + r, y1 - r)])
                if self.terrain.is_steep(p[None])[0]:
                    continue
                if self.layout.clearance(p[None])[0] < r + 0.2:
                    continue
                if all(np.hypot(*(p - q[:2])) > 2 * r + START_GAP for q in poses):
                    break
            else:
                raise ValueError(
                    f"could not place robot {i} of n_robots={n} in start_region "
                    f"{(x0, y0, x1, y1)}: make it larger or use fewer robots"
                )
            poses.append(np.array([p[0], p[1], rng.uniform(-np.pi, np.pi)]))
        return np.array(poses)

    # ------------------------------------------------------------------ step
    def step(
        self,
        v_cmd: np.ndarray,
        w_cmd: np.ndarray,
        active: np.ndarray,
        rng: np.random.Generator,
        idle_zeroed: bool = False,
    ) -> np.ndarray:
        """Advance one env step (``odometry_substeps`` physics substeps).

        Args:
            v_cmd, w_cmd: commanded linear and angular velocities ``(n,)``.
            active: robots that can move (tipped-over robots stand still).
            rng: noise source for wheel slip.
            idle_zeroed: the caller already zeroed the commands of inactive robots.

        Returns:
            Number of new contacts per robot during the step, ``(n,)``.
        """
        cfg = self.cfg
        n_sub = cfg.odometry_substeps
        dt = cfg.dt / n_sub
        n = len(v_cmd)
        before = self.contacts["counts"].copy()
        slip = rng.standard_normal((n_sub, n, 2))  # 1 + slip_std * noise, in place
        slip *= cfg.slip_std
        slip += 1.0
        if not idle_zeroed and np.count_nonzero(active) < n:
            v_cmd, w_cmd = np.where(active, v_cmd, 0.0), np.where(active, w_cmd, 0.0)
        vk = v_cmd * slip[:, :, 0]  # (substeps, n)
        wk = w_cmd * slip[:, :, 1]
        # Bodies have infinite moment: contacts never change their turn rate, so the
        # heading at each substep's start is known in advance (summed in pymunk's order).
        heading = np.empty((n_sub + 1, n))
        heading[0] = self._angles
        np.multiply(wk, dt, out=heading[1:])
        np.add.accumulate(heading, axis=0, out=heading)  # np.cumsum without its wrapper
        vel = self._velocity_buffer[:-1, :n]
        np.cos(heading[:-1], out=vel[..., 0])
        np.sin(heading[:-1], out=vel[..., 1])
        vel[..., :2] *= vk[..., None]  # both velocity components in one multiply
        vel[..., 2] = wk
        space, batch = self.space, self._batch
        if batch is not None:
            for k in range(n_sub):
                batch.set_velocities(k)
                space.step(dt)
            batch.set_velocities(n_sub)  # stop the robots
            state = batch.poses()[:n]
        else:
            set_bodies = pymunk.batch.set_space_bodies
            for row in self._velocity_rows[:-1]:
                set_bodies(space, _VELOCITIES, row)
                space.step(dt)
            set_bodies(space, _VELOCITIES, self._velocity_rows[-1])  # stop the robots
            self._state_batch.clear()
            pymunk.batch.get_space_bodies(space, _POSE_FIELDS, self._state_batch)
            state = np.frombuffer(self._state_batch.float_buf(), dtype=np.float64)
            state = state.reshape(-1, 3)[:n]
        self.poses[:] = state
        self._angles = state[:, 2].copy()  # unwrapped, as pymunk keeps them
        self.poses[:, 2] = wrap_angle(self._angles)
        return self.contacts["counts"] - before


class _BatchCalls:
    """``pymunk.batch.set_space_bodies`` / ``get_space_bodies`` with their C argument
    structs built once.

    The public functions allocate and fill a ``pmBatchedData`` struct on every
    call, and the world makes seven calls per step; here each is the same single
    C call (``cpSpaceEachBody`` with pymunk's batch iterator). Only body data is
    set and read this way: the world still steps through ``Space.step``, which
    keeps pymunk's locking, deferred removals and post-step callbacks.
    :meth:`make` returns ``None`` where this pymunk lacks these internals.
    """

    def __init__(
        self, space: pymunk.Space, rows: list[pymunk.batch.Buffer], state: pymunk.batch.Buffer
    ) -> None:
        from pymunk._chipmunk import ffi, lib

        self._lib, self._ffi = lib, ffi
        self._space_ptr = space._space
        self._set_fn = ffi.addressof(lib, "pmSpaceBodySetIteratorFuncBatched")
        self._get_fn = ffi.addressof(lib, "pmSpaceBodyGetIteratorFuncBatched")
        self._rows = rows  # keeps the buffers (and the numpy rows they point to) alive
        self._set_data = [self._struct(_VELOCITIES, row) for row in rows]
        self._state_arr = state._float_arr
        self._get_data = self._struct(_POSE_FIELDS, state)
        self._view: np.ndarray | None = None
        self._view_key: tuple = (None, -1)

    def _struct(self, fields: pymunk.batch.BodyFields, buffer: pymunk.batch.Buffer):
        data = self._ffi.new("pmBatchedData *")
        data.fields = fields.value
        data.floatArray = buffer._float_arr
        data.intArray = buffer._int_arr
        return data

    @classmethod
    def make(
        cls, space: pymunk.Space, rows: list[pymunk.batch.Buffer], state: pymunk.batch.Buffer
    ) -> _BatchCalls | None:
        """The prepared calls, or ``None`` when this pymunk lacks the expected internals."""
        try:
            return cls(space, rows, state)
        except (AttributeError, ImportError, TypeError):
            return None

    def set_velocities(self, k: int) -> None:
        """``set_space_bodies(space, VELOCITY | ANGULAR_VELOCITY, rows[k])``."""
        data = self._set_data[k]
        arr = data.floatArray
        num = arr.num
        arr.num = 0  # pymunk's iterator reads from the start
        self._lib.cpSpaceEachBody(self._space_ptr, self._set_fn, data)
        arr.num = num

    def poses(self) -> np.ndarray:
        """``(bodies, 3)`` positions and angles (``get_space_bodies`` into the state buffer).

        The array views pymunk's memory and is overwritten by the next call.
        """
        arr = self._state_arr
        arr.num = 0  # as Buffer.clear(): overwrite from the start
        self._lib.cpSpaceEachBody(self._space_ptr, self._get_fn, self._get_data)
        key = (arr.arr, arr.num)
        if key[0] != self._view_key[0] or key[1] != self._view_key[1]:
            buf = self._ffi.buffer(arr.arr, self._ffi.sizeof("cpFloat") * arr.num)
            self._view = np.frombuffer(buf, dtype=np.float64).reshape(-1, 3)
            self._view_key = key
        return self._view
