"""The particle sets of a team of robots in flat arrays, as the compiled passes update them.

A :class:`ParticleSet` is one robot's particles: its ``(3, n)`` state and ``(n,)``
weights, usually views of a team's flat arrays. A :class:`ParticleTeam` is ``R``
robots' sets joined in the block layout of :mod:`estimators.mcl._team_kernels`
(robot ``r``'s particles ``starts[r] .. ends[r] - 1``, its state the C-ordered
``(3, n_r)`` block at offset ``3 * starts[r]`` of :attr:`ParticleTeam.state`).
Sampling (:mod:`estimators.mcl.sampling`), weighting (:mod:`estimators.mcl.weighting`)
and the team passes (:mod:`estimators.mcl.batch`) operate on a team;
:class:`~estimators.mcl.filter.ParticleFilter` is one robot's view (alone, a team
of one). Joining a team reuses the arrays in place when every set is still a view of
them at its offset, so a team stepped pass after pass copies nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property
from typing import Protocol

import numpy as np

from estimators.geometry import wrap_angle_in_place
from estimators.mcl.config import MCLConfig
from estimators.mcl.likelihood_field import LFField
from estimators.mcl.occupancy import OccupancyGrid

__all__ = ["ParticleSet", "ParticleTeam", "TeamMember"]

WRAP_EVERY = 8  # motion updates between two wraps of the headings


class ParticleSet:
    """One robot's particles as the compiled passes read and write them.

    ``state`` ``(3, n)`` float32: ``x, y`` (m, from ``origin``) and heading (rad; it may
    drift outside ``[-pi, pi)`` for up to ``WRAP_EVERY`` motion updates between wraps).
    ``weights`` ``(n,)`` float64, normalized; replaced, never changed in place.
    ``origin`` ``(3, 1)`` float64: world ``x, y`` (m) of the centre of map cell (0, 0),
    and 0 (``origin_xy``: the same two floats); float32 positions keep ~1e-6 m there.
    ``state_start`` / ``weights_start``: particle offset of ``state`` / ``weights`` in the
    team array they are views of (-1: none). ``ess_cache``: ``(weights, ESS)``, the last
    effective sample size computed and the weights it belongs to.
    ``unwrapped_steps``: motion updates since the headings were last wrapped.
    """

    __slots__ = ("ess_cache", "origin", "origin_xy", "state", "state_start",
                 "unwrapped_steps", "weights", "weights_start")

    def __init__(self, origin_xy: tuple[float, float]) -> None:
        self.origin = np.array([[origin_xy[0]], [origin_xy[1]], [0.0]])
        self.origin_xy = (float(self.origin[0, 0]), float(self.origin[1, 0]))
        self.state = np.zeros((3, 0), dtype=np.float32)
        self.weights = np.zeros(0)
        self.state_start = self.weights_start = -1
        self.ess_cache: tuple[np.ndarray, float] = (self.weights, 0.0)
        self.unwrapped_steps = 0

    @property
    def n(self) -> int:
        """Number of particles."""
        return self.weights.size

    @property
    def ess(self) -> float:
        """Effective sample size ``1 / sum(w^2)`` (cached per weights array)."""
        w, ess = self.ess_cache
        if w is not self.weights:
            ess = float(1.0 / np.dot(self.weights, self.weights))
            self.ess_cache = (self.weights, ess)
        return ess

    def flat_state(self) -> np.ndarray:
        """The state as a flat ``(3 n,)`` view (made C-contiguous first if it is not)."""
        if not self.state.flags.c_contiguous:
            self.state = np.ascontiguousarray(self.state)
        return self.state.reshape(-1)

    def replace_state(self, state: np.ndarray) -> None:
        """A new ``(3, n)`` float32 state with wrapped headings, in no team array."""
        self.state = state
        self.state_start = -1
        self.unwrapped_steps = 0

    def after_motion(self) -> None:
        """Count a motion update; wrap the headings every ``WRAP_EVERY`` of them."""
        self.unwrapped_steps += 1
        if self.unwrapped_steps >= WRAP_EVERY:
            self.wrap_headings()

    def wrap_headings(self) -> None:
        """Wrap the state's headings to ``[-pi, pi)`` in place."""
        wrap_angle_in_place(self.state[2])
        self.unwrapped_steps = 0


class TeamMember(Protocol):
    """What the team passes read and call on each robot's filter."""

    grid: OccupancyGrid
    rng: np.random.Generator
    config: MCLConfig
    particle_set: ParticleSet

    @property
    def inject_probability(self) -> float: ...

    def motion_draw(self, dx: float, dy: float, dth: float) -> tuple[float, ...]: ...

    def track_evidence(self, log_evidence: float, n_eff_beams: float) -> None: ...

    def uniform_weights(self, n: int) -> np.ndarray: ...

    def lf_field(self, max_range: float) -> LFField: ...

    def lf_kernel_args(self, max_range: float | None) -> tuple: ...


_ENDS: dict[tuple[int, ...], np.ndarray] = {}  # segment ends by particle counts (not written)


class ParticleTeam:
    """``R`` robots' particle sets in flat arrays (block layout).

    Fields:

    * ``members``: the ``R`` robots' filters (:class:`TeamMember`), ``sets``: their
      :class:`ParticleSet` (one robot's view of the arrays below);
    * ``state`` ``(3 N,)`` float32: every robot's ``x, y`` (m, from its origin) and
      heading (rad) rows, robot ``r``'s ``(3, n_r)`` block at ``3 * starts[r]``;
    * ``ends`` ``(R,)`` intp: segment ends (``N = ends[-1]``); ``starts`` ``(R,)``;
    * :meth:`weights` ``(N,)`` float64, each segment normalized; ``ess`` ``(R,)``;
    * ``origins`` ``(R, 2)`` float64: world ``x, y`` (m) of each robot's state origin;
    * ``rngs``: each robot's generator (robot ``r`` draws only from ``rngs[r]``).

    Build one with :meth:`gather` (or :meth:`alone`). A pass that replaces the state
    (:func:`~estimators.mcl.sampling.resample_team`) updates ``state`` and ``ends``.
    """

    def __init__(self, members: Sequence[TeamMember], state: np.ndarray,
                 ends: np.ndarray) -> None:
        self.members = members
        self.sets = [m.particle_set for m in members]
        self.state = state
        self.ends = ends

    @classmethod
    def gather(cls, members: Sequence[TeamMember]) -> ParticleTeam:
        """The members' sets joined: their states in one flat float32 array, each set's
        state made a view of it (no copy when every state already is one, in order)."""
        sets = [m.particle_set for m in members]
        if not sets:
            return cls(members, np.zeros(0, dtype=np.float32), np.zeros(0, dtype=np.intp))
        flat = sets[0].state.base
        valid = flat is not None
        counts = []
        start = 0
        for ps in sets:
            n = ps.weights.size
            counts.append(n)
            if valid and (ps.state.base is not flat or ps.state_start != start):
                valid = False
            start += n
        key = tuple(counts)
        ends = _ENDS.get(key)
        if ends is None:
            if len(_ENDS) > 256:  # adaptive counts vary: keep the cache small
                _ENDS.clear()
            ends = _ENDS[key] = np.cumsum(np.array(counts, dtype=np.intp))
        if not (valid and flat.size == 3 * start):
            flat = np.concatenate([ps.flat_state() for ps in sets])
            start = 0
            for ps, n in zip(sets, counts, strict=True):
                ps.state = flat[3 * start:3 * (start + n)].reshape(3, n)
                ps.state_start = start
                start += n
        return cls(members, flat, ends)

    @classmethod
    def alone(cls, member: TeamMember) -> ParticleTeam:
        """A team of one robot, on its own state (no copy; its offsets are left as they are)."""
        ps = member.particle_set
        return cls((member,), ps.flat_state(), np.array([ps.weights.size]))

    def weights(self) -> np.ndarray:
        """The sets' weights in one ``(N,)`` array (a view of the last team weighting's
        output when no set replaced its weights since, else a new array)."""
        sets = self.sets
        if not sets:
            return np.zeros(0)
        w = sets[0].weights.base
        start = 0
        for ps in sets:
            if w is None or ps.weights.base is not w or ps.weights_start != start:
                break
            start += ps.weights.size
        else:
            if w.size == start:
                return w
        return np.concatenate([ps.weights for ps in sets])

    @property
    def starts(self) -> np.ndarray:
        """``(R,)`` first particle of each robot."""
        return self.ends - np.diff(self.ends, prepend=0)

    @cached_property
    def origins(self) -> np.ndarray:
        """``(R, 2)`` world ``x, y`` (m) of each set's state origin."""
        return np.array([ps.origin_xy for ps in self.sets]).reshape(-1, 2)

    @property
    def rngs(self) -> list[np.random.Generator]:
        """Each robot's generator."""
        return [m.rng for m in self.members]

    @property
    def ess(self) -> np.ndarray:
        """``(R,)`` each set's effective sample size ``1 / sum(w^2)``."""
        return np.array([ps.ess for ps in self.sets], dtype=float)
