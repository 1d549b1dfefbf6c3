"""The values one env step passes along: physics outcome, sensor readings, team beliefs.

A step is a chain of records (named tuples or a frozen dataclass: made once, never
changed afterwards, and cheap to make on every step):
:meth:`World.step <coop_loc_env.world.World.step>` returns a :class:`PhysicsOutcome`;
:meth:`SensorSuite.read <coop_loc_env.sensors.SensorSuite.read>` turns it into
:class:`Readings` (which say which sensors fired; the camera's part is computed
when first read, :class:`LazyCamera`); every estimation backend folds the readings
in and reports a :class:`Beliefs`, and the env joins them into the team's
``env.beliefs``, which the map, the observations, the renderer and the policies read.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np


class PhysicsOutcome(NamedTuple):
    """What one physics step did to the team: the one record of contacts and tipping.

    ``poses (n, 3)``: true poses at the end of the step (a snapshot);
    ``new_contacts (n,)``: contacts that began during the step; ``touching (n,)``: in
    contact at the end of the step (what a bumper switch reads); ``in_contact (n,)``:
    touched something during the step (a new contact or one held at its end: the
    collision penalty applies); ``tipped (n,)``: active robots standing on ground too
    steep (tipped over in this step).
    """

    poses: np.ndarray
    new_contacts: np.ndarray
    touching: np.ndarray
    in_contact: np.ndarray
    tipped: np.ndarray


@dataclass(frozen=True)
class Detections:
    """Robot-detector output for one step: ``k`` sightings of ``target`` by ``observer``.

    ``z`` holds (range, bearing, orientation) of the target in the observer's
    frame and ``cov`` the 3x3 noise the observer believes; ``genuine`` is
    privileged (False for false positives) and never given to estimators.
    """

    observer: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    target: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    z: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    genuine: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __len__(self) -> int:
        return len(self.observer)


@dataclass(frozen=True)
class CameraSightings:
    """The visible (observer, target) pairs of one camera frame, in (observer, target) order.

    Targets index the objects of interest first, then the robots. ``offset`` is
    the true target position minus the observer's, ``dist`` its length (> 0)
    and ``bearing`` the pixel-quantized bearings as Python floats.
    """

    observer: np.ndarray  # (k,) ints
    target: np.ndarray  # (k,) ints
    bearing: Sequence[float]
    offset: np.ndarray  # (k, 2)
    dist: np.ndarray  # (k,)


class CameraOutput(NamedTuple):
    """One camera frame's output: per robot ``(kind, id, bearing, range)`` lists (``None``:
    made from the records when read), the sightings as arrays, and per robot the
    depth-from-motion records (``None`` when no depth from motion ran: a sensor suite
    used on its own)."""

    lists: list[list[tuple[str, int, float, float]]] | None
    sightings: CameraSightings | None
    records: list[list[Any]] | None


class LazyCamera:
    """A camera frame's :class:`CameraOutput`, computed on first read.

    The camera feeds no observation, reward or estimator, so a step only queues its
    frame; whoever reads it pays for it. ``source.output_of(frame)`` computes it (the
    source processes its frames in order and hands each its value, :meth:`resolve`);
    with ``value`` the output is known already (``source`` unused).
    """

    __slots__ = ("_source", "_frame", "_value", "__weakref__")

    def __init__(self, source: Any, frame: int = 0, value: CameraOutput | None = None) -> None:
        self._source = source
        self._frame = frame
        self._value = value

    def get(self) -> CameraOutput:
        """The frame's output (computed now if it was not yet)."""
        if self._value is None:
            self._value = self._source.output_of(self._frame)
            self._source = None
        return self._value

    def resolve(self, value: CameraOutput) -> None:
        """Set the output (by the source, once it computed this frame)."""
        self._value = value
        self._source = None

    def __getstate__(self) -> tuple:
        return (self._source, self._frame, self._value)

    def __setstate__(self, state: tuple) -> None:
        self._source, self._frame, self._value = state


class SensorsFired(NamedTuple):
    """Which sensors fired in a step by their rates (for some robot of the team)."""

    gps: bool
    compass: bool
    inclinometer: bool
    range: bool
    camera: bool
    detector: bool


@dataclass(frozen=True, init=False)
class Readings:
    """Everything the team's sensors produced during one env step.

    Arrays are indexed by robot; a ``*_mask`` says which robots got a reading and
    :attr:`fired` which sensors fired by their rates this step. The camera's output
    (:attr:`camera`, :attr:`camera_sightings`, :attr:`camera_records`) is computed on
    first read. Frozen (``dataclasses.replace`` makes a changed copy).
    """

    odometry: np.ndarray  # (substeps, n, 2) measured (V, w)
    gps_mask: np.ndarray  # (n,) a fix arrived
    gps_xy: np.ndarray  # (n, 2)
    gps_var: np.ndarray  # (n,) per-axis variance the receiver reports
    gps_altitude: np.ndarray  # (n,)
    satellites: np.ndarray  # (n,) satellites in view (on every GPS step)
    compass_mask: np.ndarray
    compass: np.ndarray  # (n,)
    inclinometer_mask: np.ndarray
    pitch: np.ndarray  # (n,)
    roll: np.ndarray  # (n,)
    range_mask: np.ndarray  # (n,) a scan arrived
    ranges: np.ndarray  # (n, max_beams), max range where nothing returned; NaN pads
    camera_mask: np.ndarray
    detections: Detections
    fired: SensorsFired
    # The camera frame of this step; None: no frame (every camera output is empty).
    camera_frame: LazyCamera | None = None
    # (n,) the bumper is pressed: the robot touches an obstacle, the world's boundary or
    # another robot at the end of the step (its wheels may then spin in place). None: unknown.
    bumper: np.ndarray | None = None

    def __init__(
        self, odometry: np.ndarray, gps_mask: np.ndarray, gps_xy: np.ndarray,
        gps_var: np.ndarray, gps_altitude: np.ndarray, satellites: np.ndarray,
        compass_mask: np.ndarray, compass: np.ndarray, inclinometer_mask: np.ndarray,
        pitch: np.ndarray, roll: np.ndarray, range_mask: np.ndarray, ranges: np.ndarray,
        camera_mask: np.ndarray, detections: Detections, fired: SensorsFired,
        camera_frame: LazyCamera | None = None, bumper: np.ndarray | None = None,
    ) -> None:
        # Set once, into the instance's dict: the frozen dataclass's own __init__ sets
        # each field through object.__setattr__, several microseconds per env step.
        self.__dict__.update(
            odometry=odometry, gps_mask=gps_mask, gps_xy=gps_xy, gps_var=gps_var,
            gps_altitude=gps_altitude, satellites=satellites, compass_mask=compass_mask,
            compass=compass, inclinometer_mask=inclinometer_mask, pitch=pitch, roll=roll,
            range_mask=range_mask, ranges=ranges, camera_mask=camera_mask,
            detections=detections, fired=fired, camera_frame=camera_frame, bumper=bumper,
        )

    @property
    def camera(self) -> list[list[tuple[str, int, float, float]]]:
        """Per robot: ``(kind, id, bearing, range)`` of what its camera saw (fresh lists)."""
        if self.camera_frame is None:
            return [[] for _ in range(len(self.camera_mask))]
        out = self.camera_frame.get()
        if out.lists is None:
            return [[(c.kind, c.id, c.bearing, c.range) for c in row] for row in out.records]
        return [list(row) for row in out.lists]

    @property
    def camera_sightings(self) -> CameraSightings | None:
        """The camera's sightings as arrays, in (robot, target) order: observer, target
        index (objects of interest first, then robots), quantized bearing (a list),
        line-of-sight offsets (k, 2) and true distances (k,). None without a frame."""
        return None if self.camera_frame is None else self.camera_frame.get().sightings

    @property
    def camera_records(self) -> list[list[Any]]:
        """Per robot, the depth-from-motion records of this step's frame
        (:class:`~coop_loc_env.depth_from_motion.CameraRecord`; empty without a frame)."""
        records = None if self.camera_frame is None else self.camera_frame.get().records
        if records is None:
            return [[] for _ in range(len(self.camera_mask))]
        return [list(row) for row in records]


class ParticleSet(NamedTuple):
    """One robot's particle belief: ``states (N, 3)`` world poses, normalized ``weights
    (N,)`` and the filter's effective sample size ``ess`` (``1 / sum(w^2)``)."""

    states: np.ndarray
    weights: np.ndarray
    ess: float


class Beliefs(NamedTuple):
    """The beliefs of some robots after a step: what their estimators report.

    ``robots (k,)``: their global indices; ``mean (k, 3)``, ``cov (k, 3, 3)``: Gaussian
    summaries; ``features (k, f)``: the observation's belief block. ``samples``: for
    robots whose belief is a particle set, global index -> :class:`ParticleSet`
    (made by ``sampler``, a callable that memoizes, on first read, which must come before
    the estimators step again).
    """

    robots: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    features: np.ndarray
    sampler: Callable[[], dict[int, ParticleSet]] | None = None

    @property
    def samples(self) -> dict[int, ParticleSet]:
        """Global robot index -> particle set of each particle-filter robot (may be empty;
        made on the first read, a snapshot from then on)."""
        return {} if self.sampler is None else dict(self.sampler())


class JoinedSampler:
    """A sampler reporting what each of ``samplers`` reports, once (a picklable callable;
    samplers memoize what they return, so a record's samples stay one value)."""

    def __init__(self, samplers: list[Callable[[], dict[int, ParticleSet]]]) -> None:
        self.samplers = list(samplers)
        self._out: dict[int, ParticleSet] | None = None

    def __call__(self) -> dict[int, ParticleSet]:
        if self._out is None:
            out: dict[int, ParticleSet] = {}
            for sampler in self.samplers:
                out.update(sampler())
            self._out = out
        return self._out


class StepRecord(NamedTuple):
    """The values of one env step after the reward phase, one row per robot: the true and
    estimated poses ``(n, 3)`` and covariances ``(n, 3, 3)`` (fresh copies), the true
    position / heading errors ``(n,)``, the weighted reward terms ``{name: [float per
    robot]}`` and their sums ``rewards``, ``tipped_now`` (tipped over in this step, 0/1),
    ``new_contacts`` and ``in_contact`` (``None`` at an episode's start) and whether the
    episode is ``truncated`` (``max_cycles`` reached). The parallel env turns it into
    PettingZoo's dicts; :func:`coop_loc_env.vector_env` stacks it over its worlds."""

    true_pose: np.ndarray
    est_pose: np.ndarray
    pose_cov: np.ndarray
    err_xy: np.ndarray
    err_th: np.ndarray
    terms: dict[str, list[float]]
    rewards: list[float]
    tipped_now: np.ndarray
    new_contacts: np.ndarray
    in_contact: np.ndarray | None
    truncated: bool
