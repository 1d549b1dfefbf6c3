"""Raw access to pymunk's Chipmunk internals, the one place the world reads C memory.

Why: pymunk does not pickle the bias velocities its solver leaves on the bodies
(a copied world would then continue differently), its public contact API costs a
Python callback per arbiter and body, and its batch calls rebuild their C argument
structs on every call. Here those are read and written directly: the bias velocity
at hard-coded offsets of Chipmunk's ``cpBody`` (checked once against a probe body,
:func:`bias_layout_ok`), the space's arbiters through ``_get_arbiters`` and the batch
iterators with prebuilt structs. Every entry point falls back to pymunk's public API
(or does nothing) where this pymunk lacks the expected internals.
"""

from __future__ import annotations

import functools

import numpy as np
import pymunk
import pymunk.batch

VELOCITIES = pymunk.batch.BodyFields.VELOCITY | pymunk.batch.BodyFields.ANGULAR_VELOCITY
POSE_FIELDS = pymunk.batch.BodyFields.POSITION | pymunk.batch.BodyFields.ANGLE


class ContactReader:
    """Which robots touch a shape after the last physics step, from the space's arbiters.

    Args:
        space: the physics space.
        bodies: the robots' bodies, in robot order.
    """

    def __init__(self, space: pymunk.Space, bodies: list[pymunk.Body]) -> None:
        self.space = space
        self.bodies = bodies
        self._shape_robot: dict[int, int] = {}  # robot index of each robot shape's C pointer
        self._c = None
        try:
            from pymunk._chipmunk import ffi, lib
        except ImportError:
            return
        if not hasattr(space, "_get_arbiters"):
            return
        for i, body in enumerate(bodies):
            for shape in body.shapes:
                self._shape_robot[int(ffi.cast("uintptr_t", shape._shape))] = i
        self._c = (ffi, lib)

    @classmethod
    def make(cls, space: pymunk.Space | None, bodies: list[pymunk.Body]) -> ContactReader | None:
        """The reader of ``space`` (``None`` before the space is built)."""
        return None if space is None else cls(space, bodies)

    def touching(self) -> np.ndarray:
        """Robots touching a shape after the last physics step ``(n,)``."""
        touching = np.zeros(len(self.bodies), dtype=bool)
        if self._c is None:  # this pymunk hides its contacts: ask each body
            for i, body in enumerate(self.bodies):
                found: list = []
                body.each_arbiter(lambda arb, out=found: out.append(arb))
                touching[i] = any(arb.contact_point_set.points for arb in found)
            return touching
        ffi, lib = self._c
        space = self.space
        arbiters = space._get_arbiters()
        if not arbiters:
            return touching
        stamp = lib.cpSpaceGetTimestamp(space._space)
        robot = self._shape_robot
        for arb in arbiters:
            if arb.stamp != stamp or arb.count == 0:  # not touching in the last step
                continue
            for shape in (arb.a, arb.b):
                i = robot.get(int(ffi.cast("uintptr_t", shape)))
                if i is not None:
                    touching[i] = True
        return touching


# Chipmunk's cpBody, read as doubles: position at 8-9, velocity 10-11, angle 14, turn rate
# 15, then (after force, torque, transform and user data) the bias velocity at 24-26.
_BODY_BIAS_SLOTS = (24, 25, 26)


@functools.cache
def bias_layout_ok() -> bool:
    """Whether this pymunk's cpBody has the layout :data:`_BODY_BIAS_SLOTS` assumes."""
    try:
        from pymunk._chipmunk import ffi
    except ImportError:
        return False
    body = pymunk.Body(1.5, 2.5)
    body.position, body.velocity = (11.0, 12.0), (13.0, 14.0)
    body.angle, body.angular_velocity = 15.0, 16.0
    try:
        raw = ffi.cast("double *", body._body)
        known = [raw[i] for i in (2, 4, 8, 9, 10, 11, 14, 15)]
    except (AttributeError, TypeError):
        return False
    return known == [1.5, 2.5, 11.0, 12.0, 13.0, 14.0, 15.0, 16.0] and all(
        raw[i] == 0.0 for i in _BODY_BIAS_SLOTS
    )


def bias_of(body: pymunk.Body) -> tuple[float, ...] | None:
    """The bias velocity ``(vx, vy, w)`` the solver left on ``body`` for its next position
    update (pymunk keeps it in C and does not pickle it); ``None`` if unreadable."""
    if not bias_layout_ok():
        return None
    from pymunk._chipmunk import ffi

    raw = ffi.cast("double *", body._body)
    return tuple(raw[i] for i in _BODY_BIAS_SLOTS)


def set_bias(body: pymunk.Body, values: tuple[float, ...] | None) -> None:
    if values is None or not bias_layout_ok():
        return
    from pymunk._chipmunk import ffi

    raw = ffi.cast("double *", body._body)
    for i, value in zip(_BODY_BIAS_SLOTS, values, strict=True):
        raw[i] = value


_SPACE_STEP_STATE = ("_locked", "_bodies_to_check", "_removed_shapes", "_add_later",
                     "_remove_later", "_post_step_callbacks", "_remove")


def finish_step(space: pymunk.Space) -> None:
    """The end of ``pymunk.Space.step``: what callbacks queued during the C step."""
    space.add(*space._add_later)
    space._add_later.clear()
    removed = set()
    while space._remove_later:
        to_remove, _ = space._remove_later.popitem()
        if to_remove not in removed:
            removed.add(to_remove)
            space._remove(to_remove)
    for key in space._post_step_callbacks:
        space._post_step_callbacks[key](space)
    space._post_step_callbacks.clear()


class BatchCalls:
    """``pymunk.batch.set_space_bodies`` / ``get_space_bodies`` with their C argument
    structs built once.

    The public functions allocate and fill a ``pmBatchedData`` struct on every
    call, and the world makes seven calls per step; here each is the same single
    C call (``cpSpaceEachBody`` with pymunk's batch iterator). :meth:`step` is
    ``Space.step`` without its Python bookkeeping when there is none to do: the
    C step under pymunk's lock, then pymunk's handling of deferred additions,
    removals and post-step callbacks only when a callback queued some.
    :meth:`make` returns ``None`` where this pymunk lacks these internals.
    """

    def __init__(
        self, space: pymunk.Space, rows: list[pymunk.batch.Buffer], state: pymunk.batch.Buffer
    ) -> None:
        from pymunk._chipmunk import ffi, lib

        for name in _SPACE_STEP_STATE:  # what :meth:`step` reads of pymunk's Space
            getattr(space, name)
        self._lib, self._ffi = lib, ffi
        self._space_ptr = space._space
        self._set_fn = ffi.addressof(lib, "pmSpaceBodySetIteratorFuncBatched")
        self._get_fn = ffi.addressof(lib, "pmSpaceBodyGetIteratorFuncBatched")
        self._rows = rows  # keeps the buffers (and the numpy rows they point to) alive
        self._set_data = [self._struct(VELOCITIES, row) for row in rows]
        self._state_arr = state._float_arr
        self._get_data = self._struct(POSE_FIELDS, state)
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
    ) -> BatchCalls | None:
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

    def step(self, space: pymunk.Space, dt: float) -> None:
        """``space.step(dt)``: the C step under pymunk's lock, then pymunk's own handling
        of whatever callbacks queued (additions, removals, post-step callbacks), if any."""
        if space._bodies_to_check:  # pymunk checks new bodies' masses first
            space.step(dt)
            return
        space._locked = True
        try:
            self._lib.cpSpaceStep(self._space_ptr, dt)
            space._removed_shapes.clear()
        finally:
            space._locked = False
        if space._add_later or space._remove_later or space._post_step_callbacks:
            finish_step(space)

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
