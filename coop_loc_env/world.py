"""The simulated world: static layout, terrain, and skid-steer robots on pymunk.

The layout (obstacles, canopy, terrain) comes from ``cfg.layout_seed`` so the
map is the same in every episode; the episode seed places the robots and
drives all noise. Robot motion follows Eq. 1 of the outdoor paper: the
commanded ``(V, w)`` with multiplicative slip noise sets each body's velocity
for every physics substep, and pymunk resolves collisions with obstacles,
objects of interest, the world boundary and other robots.

Physics holds every accepted speed: each odometry substep is split into as many
physics steps as keep a robot's travel per physics step within 0.4 of its radius
(:data:`MAX_TRAVEL_PER_RADIUS`), so a robot pushed into a wall, an obstacle or
another robot never sinks past their middle and out the other side; speeds that
would need more than :data:`MAX_PHYSICS_STEPS` physics steps per odometry
substep are refused when the world is built.

What pymunk keeps in C and does not expose (solver bias velocities, arbiters, batch
argument structs) is read in :mod:`coop_loc_env.chipmunk_raw`, the one module that
touches Chipmunk's memory.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk
import pymunk.batch

from coop_loc_env._step_kernels import settle_poses, substep_commands, substep_velocities
from coop_loc_env.chipmunk_raw import (
    POSE_FIELDS,
    VELOCITIES,
    BatchCalls,
    ContactReader,
    bias_of,
    set_bias,
)
from coop_loc_env.config import START_GAP, Obstacle, ScenarioConfig
from coop_loc_env.raycast import RayScene
from coop_loc_env.records import PhysicsOutcome
from coop_loc_env.terrain import HeightField

ROBOT_COLLISION_TYPE = 1
#: Most a robot may travel in one physics step, in robot radii. pymunk lets a body
#: pressed into a surface sink about one step of travel before pushing it out, two when
#: another robot pushes it there: 0.4 radius keeps that within 0.8 radius, short of the
#: middle of two robots meeting head-on or of a robot and the thinnest wall. Every
#: scenario's default speed needs one physics step per odometry substep.
MAX_TRAVEL_PER_RADIUS = 0.4
#: Most physics steps per odometry substep (faster robots are refused).
MAX_PHYSICS_STEPS = 16
_WALL_RADIUS = 0.05


def _count_contact(arbiter: pymunk.Arbiter, space: pymunk.Space, data: dict) -> None:
    """pymunk begin-callback: count a new contact for the robot(s) involved."""
    for shape in arbiter.shapes:
        index = getattr(shape, "robot_index", None)
        if index is not None:
            data["counts"][index] += 1


def physics_steps_for(cfg: ScenarioConfig, max_speed: float) -> int:
    """Physics steps per odometry substep that hold robots of ``max_speed`` (m/s).

    Raises ``ValueError`` naming the fastest speed the world can hold when more
    than :data:`MAX_PHYSICS_STEPS` would be needed.
    """
    dt = cfg.dt / cfg.odometry_substeps
    reach = MAX_TRAVEL_PER_RADIUS * cfg.robot_radius
    steps = max(1, math.ceil(max_speed * dt / reach * (1 - 1e-9)))  # no rounding up at a limit
    if steps > MAX_PHYSICS_STEPS:
        limit = MAX_PHYSICS_STEPS * reach / dt
        raise ValueError(
            f"max_speed {max_speed:g} m/s is faster than the physics can hold: robots of "
            f"robot_radius {cfg.robot_radius:g} m with odometry substeps of {dt:g} s "
            f"must keep max_speed <= {limit:g} m/s (raise odometry_rate to go faster)"
        )
    return steps


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
        self.physics_steps = physics_steps_for(cfg, float(self.max_speed.max()))
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
        # allow little slop so a robot pushing into a rock stays at its surface. The
        # bias is the share of an overlap left after one second; with several physics
        # steps per substep it shrinks so that each step corrects the same share.
        space.collision_bias = pow(1.0 - 0.9, 60 * self.physics_steps)
        space.collision_slop = 0.005
        # Contacts that stop touching are dropped at once, not kept for 3 steps: a copy
        # of the space (which rebuilds the cached contacts imperfectly) then continues
        # exactly as the original.
        space.collision_persistence = 1
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
        self._index_shapes()

    def _index_shapes(self) -> None:
        """The contact reader of the robots' shapes (rebuilt after unpickling)."""
        self._contact_reader = ContactReader.make(self.space, self.bodies)

    def _make_batch_buffers(self) -> None:
        """Buffers for pymunk's batch API (rebuilt after unpickling: they hold C pointers).

        The velocity buffer has one row per body pymunk iterates (the robots
        first, in order, then the static body), per substep, plus a final
        all-zero row that stops the robots.
        """
        probe = pymunk.batch.Buffer()
        pymunk.batch.get_space_bodies(self.space, POSE_FIELDS, probe)
        n_bodies = len(probe.float_buf()) // (3 * 8)
        self._velocity_buffer = np.zeros((self.cfg.odometry_substeps + 1, n_bodies, 3))
        self._velocity_rows = []
        for row in self._velocity_buffer:
            self._velocity_rows.append(pymunk.batch.Buffer())
            self._velocity_rows[-1].set_float_buf(row)
        self._state_batch = pymunk.batch.Buffer()
        self._batch = BatchCalls.make(self.space, self._velocity_rows, self._state_batch)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("_velocity_buffer", "_velocity_rows", "_state_batch", "_batch",
                    "_contact_reader"):
            state.pop(key, None)
        # pymunk pickles the bodies and the contacts, but not the bias velocities its
        # solver left on the bodies to push them out of overlaps on the next substep.
        state["_bias_velocities"] = [bias_of(body) for body in self.bodies]
        return state

    def __setstate__(self, state: dict) -> None:
        bias = state.pop("_bias_velocities", None)
        self.__dict__.update(state)
        if bias is not None:
            for body, values in zip(self.bodies, bias, strict=True):
                set_bias(body, values)
        if self.space is not None:
            self._make_batch_buffers()
            self._index_shapes()

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
    ) -> PhysicsOutcome:
        """Advance one env step (``odometry_substeps`` substeps of ``physics_steps`` each).

        Args:
            v_cmd, w_cmd: commanded linear and angular velocities ``(n,)``.
            active: robots that can move (tipped-over robots stand still).
            rng: noise source for wheel slip.
            idle_zeroed: the caller already zeroed the commands of inactive robots.

        Returns:
            The step's :class:`~coop_loc_env.records.PhysicsOutcome`: the new poses
            (also in :attr:`poses`), new contacts, contacts at the end and during the
            step, and the active robots now on ground too steep (tipped over).
        """
        cfg = self.cfg
        n_sub = cfg.odometry_substeps
        dt = cfg.dt / n_sub
        n_phys = self.physics_steps
        dt_phys = dt / n_phys
        n = len(v_cmd)
        counts = self.contacts["counts"]
        before = counts.copy()
        slip = rng.standard_normal((n_sub, n, 2))  # 1 + slip_std * noise
        if not idle_zeroed and np.count_nonzero(active) < n:
            v_cmd, w_cmd = np.where(active, v_cmd, 0.0), np.where(active, w_cmd, 0.0)
        # Bodies have infinite moment: contacts never change their turn rate, so the
        # heading at each substep's start is known in advance (summed in pymunk's order;
        # with several physics steps per substep, equal to pymunk's up to rounding).
        vk, wk = np.empty((n_sub, n)), np.empty((n_sub, n))
        heading = np.empty((n_sub + 1, n))
        substep_commands(v_cmd, w_cmd, slip, float(cfg.slip_std), self._angles, dt, vk, wk,
                         heading)
        vel = self._velocity_buffer[:-1, :n]
        np.cos(heading[:-1], out=vel[..., 0])
        np.sin(heading[:-1], out=vel[..., 1])
        substep_velocities(vel, vk, wk)
        state = self._advance(n_sub, n_phys, dt, dt_phys)
        touching = self._contact_reader.touching()
        new = np.empty(n, dtype=counts.dtype)
        in_contact = np.empty(n, dtype=bool)
        # Poses (headings wrapped, the unwrapped ones kept), new contacts and in_contact.
        settle_poses(state, self.poses, self._angles, counts, before, touching, new, in_contact)
        poses = self.poses.copy()
        tipped = self.terrain.is_steep(poses[:, :2], active)
        return PhysicsOutcome(poses, new, touching, in_contact, tipped)

    def _advance(self, n_sub: int, n_phys: int, dt: float, dt_phys: float) -> np.ndarray:
        """Run the physics substeps with the velocities already in the buffer and stop the
        robots; returns pymunk's ``(bodies, 3)`` positions and angles."""
        space, batch = self.space, self._batch
        if batch is not None:
            if n_phys == 1:
                for k in range(n_sub):
                    batch.set_velocities(k)
                    batch.step(space, dt)
            else:  # the commanded velocity is set again before every physics step
                for k in range(n_sub):
                    for _ in range(n_phys):
                        batch.set_velocities(k)
                        batch.step(space, dt_phys)
            batch.set_velocities(n_sub)  # stop the robots
            state = batch.poses()
        else:
            set_bodies = pymunk.batch.set_space_bodies
            for row in self._velocity_rows[:-1]:
                for _ in range(n_phys):
                    set_bodies(space, VELOCITIES, row)
                    space.step(dt_phys)
            set_bodies(space, VELOCITIES, self._velocity_rows[-1])  # stop the robots
            self._state_batch.clear()
            pymunk.batch.get_space_bodies(space, POSE_FIELDS, self._state_batch)
            state = np.frombuffer(self._state_batch.float_buf(), dtype=np.float64)
            state = state.reshape(-1, 3)
        return state
