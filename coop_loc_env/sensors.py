"""Sensor models: odometry, DGPS, compass, inclinometer, range finder, camera, robot detector,
bumper.

Every sensor reads the whole team at once (numpy over robots), has its own
rate (``*_rate`` in Hz, defaults from the outdoor paper's Table 1) and noise
model, and is switched on per robot by its :class:`~coop_loc_env.config.RobotSpec`.
A sensor with rate ``f`` fires on the env steps where ``floor(t * f)``
changes; rates above ``1 / dt`` fire every step (odometry instead runs at its
full rate through the physics substeps). The records a read returns are in
:mod:`coop_loc_env.records`.

One file (past 600 lines) because every sensor model reads the suite's shared
per-team tables (ray casters, sight shapes, idle arrays) inside one read, whose
order of draws from the episode's random stream defines every episode.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from coop_loc_env._step_kernels import noisy_ranges_into
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.raycast import CHANNEL, FanCaster, circles_block, ray_segments
from coop_loc_env.records import (
    CameraOutput,
    CameraSightings,
    Detections,
    LazyCamera,
    Readings,
    SensorsFired,
)
from coop_loc_env.world import World
from estimators.geometry import wrap_angle


def _no_detections() -> Detections:
    """An empty, read-only :class:`Detections` (shared by steps when the detector is idle)."""
    empty = Detections()
    for arr in (empty.observer, empty.target, empty.z, empty.cov, empty.genuine):
        arr.flags.writeable = False
    return empty


_NO_DETECTIONS = _no_detections()
_NO_SIGHTINGS = CameraSightings(
    np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp), (), np.zeros((0, 2)), np.zeros(0)
)
for _arr in (_NO_SIGHTINGS.observer, _NO_SIGHTINGS.target, _NO_SIGHTINGS.offset,
             _NO_SIGHTINGS.dist):
    _arr.flags.writeable = False


def _noisy_ranges(
    ranges: np.ndarray, std: np.ndarray | float, rmax: np.ndarray | float,
    rng: np.random.Generator,
) -> np.ndarray:
    """True ``ranges`` plus Gaussian noise of ``std``, clipped to ``[0, rmax]``; beams
    that returned nothing (``ranges >= rmax``) read exactly ``rmax``. A new array."""
    out = rng.standard_normal(ranges.shape)
    out *= std
    out += ranges
    np.maximum(out, 0.0, out=out)
    np.minimum(out, rmax, out=out)
    np.copyto(out, rmax, where=ranges >= rmax)
    return out


UNMEASURED_ORIENTATION_STD = 1e3
"""Std (rad) of an orientation the detector does not measure: uninformative to any filter."""


def without_orientation(det: Detections) -> Detections:
    """``det`` with range and bearing only: orientation 0 with an uninformative variance."""
    z, cov = det.z.copy(), det.cov.copy()
    z[:, 2] = 0.0
    cov[:, 2, :] = cov[:, :, 2] = 0.0
    cov[:, 2, 2] = UNMEASURED_ORIENTATION_STD**2
    return Detections(det.observer, det.target, z, cov, det.genuine)


def scan_minimum_detections(
    det: Detections, ranges: np.ndarray, scanned: np.ndarray, beam_angles: Sequence[np.ndarray],
    radius: float, max_range: float,
) -> Detections:
    """Madhavan et al.'s laser-based relative measurement: the minimum of the observer's scan.

    The observer takes the closest return of its laser profile for the teammate it
    identified (of its detections, the one read nearest; the teammate tells who it
    is and sends its pose): range = that return + ``radius`` (the robot's centre
    behind its surface), bearing = the beam's angle. Whatever the minimum hits (a
    tree, a wall) is taken for the teammate, as in the paper. Observers without a
    scan this step, or whose minimum lies beyond ``max_range``, give no detection.
    """
    keep, z = [], det.z.copy()
    for a in np.unique(det.observer):
        rows = np.flatnonzero(det.observer == a)
        if not scanned[a]:
            continue
        scan = ranges[a, : len(beam_angles[a])]
        if not np.isfinite(scan).any() or np.nanmin(scan) + radius > max_range:
            continue
        k = rows[np.argmin(det.z[rows, 0])]
        beam = int(np.nanargmin(scan))
        z[k, 0], z[k, 1] = scan[beam] + radius, beam_angles[a][beam]
        keep.append(k)
    if not keep:
        return _NO_DETECTIONS
    k = np.array(keep)
    return Detections(det.observer[k], det.target[k], z[k], det.cov[k], det.genuine[k])


def beam_angles(cfg: ScenarioConfig, sonar: bool) -> np.ndarray:
    """Robot-frame beam angles of a laser or sonar: a full circle is split in equal
    sectors (no beam twice at +-pi), a narrower field of view spans both edges."""
    count = cfg.sonar_beams if sonar else cfg.laser_beams
    fov = np.deg2rad(cfg.sonar_fov_deg if sonar else cfg.laser_fov_deg)
    if fov >= 2 * np.pi - 1e-9:
        return -np.pi + (np.arange(count) + 0.5) * 2 * np.pi / count
    return np.linspace(-fov / 2, fov / 2, count)


def _due(step: int, dt: float, rate: float) -> bool:
    """Whether a sensor of ``rate`` Hz fires during env step ``step`` (0-based)."""
    return int((step + 1) * dt * rate + 1e-9) > int(step * dt * rate + 1e-9)


FIRED_BLOCK = 1024  # env steps of sensor firing looked up per table (SensorSuite.fired)
# Every SensorsFired value, indexed by its code (bit i: field i).
_FIRED_PATTERNS = tuple(SensorsFired(*(bool(code >> bit & 1) for bit in range(6)))
                        for code in range(64))


class SensorSuite:
    """All sensors of a team; call :meth:`read` once per env step."""

    def __init__(self, cfg: ScenarioConfig, world: World, camera_lists: bool = True) -> None:
        self.cfg = cfg
        self.world = world
        n = cfg.n_robots
        specs = [cfg.robot_spec(i) for i in range(n)]
        self.has_gps = np.array([s.has_gps for s in specs])
        self.has_compass = np.array([s.has_compass for s in specs])
        self.has_incl = np.array([s.has_inclinometer for s in specs])
        self.has_range = np.array([s.has_range_sensor for s in specs])
        self.is_sonar = np.array([s.range_sensor == "sonar" for s in specs])
        self.has_camera = np.array([s.has_camera for s in specs])
        self.has_detector = np.array([s.has_detector for s in specs])
        self.beam_angles = [beam_angles(self.cfg, sonar) for sonar in self.is_sonar]
        self.max_beams = max(len(b) for b in self.beam_angles)
        self.range_max = np.where(self.is_sonar, cfg.sonar_max_range, cfg.laser_max_range)
        self.range_std = np.where(self.is_sonar, cfg.sonar_range_std, cfg.laser_range_std)
        self._build_ray_tables()
        self._idle: dict[str, np.ndarray] | None = None
        self._pairs: tuple | None = None
        self._any_camera = bool(self.has_camera.any())
        self._fired_start = 0
        self._fired_codes: list[int] = []  # SensorSuite.fired's table, from _fired_start
        # Whether camera_frame makes (kind, id, bearing, noisy range) lists; the env's
        # suite does not, as depth from motion replaces those ranges.
        self.camera_lists = camera_lists
        self._odo_std = np.array([cfg.odom_v_std, cfg.odom_w_std])
        self._any_detector = bool(self.has_detector.any())
        self._not_self: np.ndarray | None = None
        self._masked_key: tuple[bytes, int] | None = None
        self._masked: tuple[np.ndarray, np.ndarray] = (np.zeros(0, int), np.zeros(0, int))
        scene, sight = world.layout.scene, CHANNEL["sight"]
        self._sight_shapes = (
            scene.circle_centers[scene.circle_mask[:, sight]],
            scene.circle_radii[scene.circle_mask[:, sight]],
            scene.seg_a[scene.seg_mask[:, sight]],
            scene.seg_b[scene.seg_mask[:, sight]],
        )

    def _build_ray_tables(self) -> None:
        """Precompute, for every robot's range sensor, its sub-ray angles in the robot frame.

        A sonar beam is a wide cone: three sub-rays across it, the shortest wins.
        """
        cfg = self.cfg
        sonar_half = 0.5 * np.deg2rad(cfg.sonar_fov_deg) / cfg.sonar_beams
        rows, beams, angles, lasers = [], [], [], []
        for i in np.nonzero(self.has_range)[0]:
            for b, ang in enumerate(self.beam_angles[i]):
                subs = (ang - sonar_half, ang, ang + sonar_half) if self.is_sonar[i] else (ang,)
                for a in subs:
                    rows.append(i)
                    beams.append(b)
                    angles.append(a)
                    lasers.append(not self.is_sonar[i])
        self._ray_robot = np.array(rows, dtype=int)
        self._ray_beam = np.array(beams, dtype=int)
        self._ray_angle = np.array(angles, dtype=float)
        laser = np.array(lasers, dtype=bool)
        ray_range = self.range_max[self._ray_robot] if len(rows) else np.zeros(0)
        self._ray_groups = [
            (sel, FanCaster(self.world.layout.scene, CHANNEL[name], self._ray_robot[sel],
                            self._ray_angle[sel], ray_range[sel]))
            for name, is_laser in (("laser", True), ("sonar", False))
            if len(sel := np.nonzero(laser == is_laser)[0])
        ]
        self._one_ray_per_beam = len(set(zip(rows, beams, strict=True))) == len(rows)
        n = self.cfg.n_robots
        self._beam_pad = np.arange(self.max_beams)[None] >= np.array(
            [len(b) for b in self.beam_angles]
        )[:, None]
        self._no_range = ~self.has_range
        self._robot_radii = np.full(n, self.cfg.robot_radius)
        self._robot_radii.flags.writeable = False  # constant for the episode
        # Fast path: one caster whose rays are exactly the (robot, beam) grid, row-major,
        # with one noise level and one maximum range for the whole team (all lasers).
        grid = len(self._ray_groups) == 1 and np.array_equal(
            self._ray_robot * self.max_beams + self._ray_beam, np.arange(n * self.max_beams)
        )
        uniform = len(set(self.range_max.tolist())) == 1 and len(set(self.range_std.tolist())) == 1
        self._grid_scan = bool(grid and uniform)

    # ------------------------------------------------------------------ read
    def fired(self, step: int, n: int | None = None) -> SensorsFired:
        """Which sensors fire during env step ``step`` (0-based) by their rates; a sensor
        no robot carries does not fire (the detector also needs two of the ``n`` robots
        read, the team by default).

        Looked up in a table of :data:`FIRED_BLOCK` steps made at once with numpy (the
        same float operations as :func:`_due`), as it is asked on every step.
        """
        if n is not None and n != self.cfg.n_robots:
            return self._fired_at(step, n)
        k = step - self._fired_start
        codes = self._fired_codes
        if not 0 <= k < len(codes):
            self._fired_start = step - step % FIRED_BLOCK
            self._fired_codes = codes = self._fired_table(self._fired_start)
            k = step - self._fired_start
        return _FIRED_PATTERNS[codes[k]]

    def _fired_at(self, step: int, n: int) -> SensorsFired:
        """:meth:`fired` of one step, for a read of ``n`` robots."""
        cfg, dt = self.cfg, self.cfg.dt
        return SensorsFired(
            _due(step, dt, cfg.gps_rate), _due(step, dt, cfg.compass_rate),
            _due(step, dt, cfg.inclinometer_rate),
            _due(step, dt, cfg.laser_rate) and bool(len(self._ray_robot)),
            _due(step, dt, cfg.camera_rate) and self._any_camera,
            _due(step, dt, cfg.detector_rate) and self._any_detector and n > 1,
        )

    def _fired_table(self, start: int) -> list[int]:
        """Codes (bit ``i``: field ``i`` of :class:`SensorsFired`) of steps ``start ..
        start + FIRED_BLOCK - 1``."""
        cfg = self.cfg
        rates = (cfg.gps_rate, cfg.compass_rate, cfg.inclinometer_rate, cfg.laser_rate,
                 cfg.camera_rate, cfg.detector_rate)
        carried = (True, True, True, bool(len(self._ray_robot)), self._any_camera,
                   self._any_detector and cfg.n_robots > 1)
        steps = np.arange(start, start + FIRED_BLOCK, dtype=np.float64)
        codes = np.zeros(FIRED_BLOCK, dtype=np.int64)
        for bit, (rate, has) in enumerate(zip(rates, carried, strict=True)):
            if has:  # int(x + 1e-9) of a positive x is its truncation, as in _due
                due = np.trunc((steps + 1) * cfg.dt * rate + 1e-9) > np.trunc(
                    steps * cfg.dt * rate + 1e-9)
                codes |= due.astype(np.int64) << bit
        return codes.tolist()

    def read(
        self,
        step: int,
        poses: np.ndarray,
        odom_cmd: np.ndarray,
        rng: np.random.Generator,
        active: np.ndarray,
        touching: np.ndarray | None = None,
        camera: Callable[[np.ndarray, np.ndarray], LazyCamera | None] | None = None,
    ) -> Readings:
        """Read every sensor due at env step ``step``.

        Args:
            step: env step index (0-based) that just finished.
            poses: true poses after the step ``(n, 3)``.
            odom_cmd: wheel-encoder truth per substep ``(substeps, n, 2)``, or ``(n, 2)``
                when it is the same at every substep.
            rng: the episode's noise generator.
            active: robots still in the episode.
            touching: which robots touch something at the end of the step (the physics'
                :attr:`~coop_loc_env.records.PhysicsOutcome.touching`): the bumpers read
                it; ``None``: the bumpers are unknown.
            camera: hands the camera frame elsewhere: called every step as
                ``camera(poses, camera_mask)`` (the mask all False without a frame), it
                returns the frame's lazily computed output. ``None``: the frame is
                computed here from ``rng``.
        """
        cfg = self.cfg
        n = len(poses)
        fired = self.fired(step, n)
        odo = rng.standard_normal((cfg.odometry_substeps, n, 2))
        odo *= self._odo_std
        odo += odom_cmd
        idle = self._idle_readings(n)
        if fired.gps:
            gps_mask, gps_xy, gps_var, gps_alt, sats = self._gps(poses, rng, active)
        else:
            gps_mask, gps_xy, gps_var, gps_alt, sats = (
                idle["gps_mask"], idle["gps_xy"], idle["gps_var"], idle["gps_alt"], idle["sats"]
            )
        compass_mask, compass = idle["mask"], idle["zeros"]
        if fired.compass:
            compass_mask = self.has_compass & active
            compass = wrap_angle(poses[:, 2] + cfg.compass_std * rng.standard_normal(n))
        incl_mask, pitch, roll = idle["mask"], idle["zeros"], idle["zeros"]
        if fired.inclinometer:
            incl_mask = self.has_incl & active
            p, r = self.world.terrain.pitch_roll(poses)
            pitch = p + cfg.inclinometer_std * rng.standard_normal(n)
            roll = r + cfg.inclinometer_std * rng.standard_normal(n)
        range_mask, ranges = idle["mask"], idle["ranges"]
        if fired.range:
            range_mask = self.has_range & active
            ranges = self._scan(poses, rng, active)
        camera_mask = self.has_camera & active if fired.camera else idle["mask"]
        if camera is not None:
            frame = camera(poses, camera_mask)
        else:
            frame = self._own_frame(poses, rng, camera_mask) if fired.camera else None
        detections = _NO_DETECTIONS
        if fired.detector:
            detections = self._detections(poses, rng, active, ranges, range_mask)
        return Readings(
            odometry=odo, gps_mask=gps_mask, gps_xy=gps_xy, gps_var=gps_var,
            gps_altitude=gps_alt, satellites=sats, compass_mask=compass_mask,
            compass=compass, inclinometer_mask=incl_mask, pitch=pitch, roll=roll,
            range_mask=range_mask, ranges=ranges, camera_mask=camera_mask,
            detections=detections, fired=fired, camera_frame=frame,
            bumper=None if touching is None else touching & active,
        )

    def _own_frame(
        self, poses: np.ndarray, rng: np.random.Generator, camera_mask: np.ndarray
    ) -> LazyCamera:
        """This step's camera frame computed now, from ``rng`` (a suite used on its own)."""
        lists, sightings = self.camera_frame(poses, rng, camera_mask)
        return LazyCamera(None, value=CameraOutput(lists, sightings, None))

    def _detections(
        self, poses: np.ndarray, rng: np.random.Generator, active: np.ndarray,
        ranges: np.ndarray, range_mask: np.ndarray,
    ) -> Detections:
        """The robot detector's sightings, in the configured detection model."""
        cfg = self.cfg
        detections = self._detect(poses, rng, active)
        if cfg.detection_model == "scan_min":
            detections = scan_minimum_detections(
                detections, ranges, range_mask, self.beam_angles, cfg.robot_radius,
                cfg.detector_range,
            )
        if not cfg.detection_orientation and len(detections):
            detections = without_orientation(detections)
        return detections

    def _idle_readings(self, n: int) -> dict[str, np.ndarray]:
        """Read-only arrays standing for sensors that did not fire this step (shared)."""
        if self._idle is None or len(self._idle["mask"]) != n:
            idle = {
                "mask": np.zeros(n, dtype=bool),
                "zeros": np.zeros(n),
                "gps_mask": np.zeros(n, dtype=bool),
                "gps_xy": np.zeros((n, 2)),
                "gps_var": np.full(n, np.inf),
                "gps_alt": np.full(n, np.nan),
                "sats": np.zeros(n, dtype=int),
                "ranges": np.full((n, self.max_beams), np.nan),
            }
            for arr in idle.values():
                arr.flags.writeable = False
            self._idle = idle
        return self._idle

    # ------------------------------------------------------------------ DGPS
    def _gps(self, poses: np.ndarray, rng: np.random.Generator, active: np.ndarray):
        """Satellites fall under canopy; variance ~ 1/NOS; no fix below 4; multipath outliers."""
        cfg = self.cfg
        n = len(poses)
        depth = self.world.layout.under_canopy(poses[:, :2])
        lo, hi = cfg.gps_open_sky_satellites
        clo, chi = cfg.gps_canopy_satellites
        open_sky = rng.integers(lo, hi + 1, size=n)
        canopy = rng.integers(clo, chi + 1, size=n)
        if np.count_nonzero(depth):
            blend = depth / 0.5
            np.maximum(blend, 0.0, out=blend)  # np.clip without its wrapper
            np.minimum(blend, 1.0, out=blend)
            sats = np.rint((1 - blend) * open_sky + blend * canopy).astype(int)
        else:  # all under open sky: the blend is 0 and the count is the open-sky draw
            sats = open_sky
        if np.count_nonzero(self.has_gps) < n:
            sats = np.where(self.has_gps, sats, 0)
        fix = active & (sats >= 4)  # robots without a receiver see 0 satellites
        safe = np.maximum(sats, 1)
        var = cfg.gps_std**2 * cfg.gps_reference_satellites / safe
        noise = rng.standard_normal((n, 2))
        noise *= np.sqrt(var)[:, None]
        multipath = rng.random(n) < cfg.gps_multipath_prob
        outlier = rng.standard_normal((n, 2))  # drawn every time: it keeps the stream fixed
        if np.count_nonzero(multipath):
            noise += multipath[:, None] * outlier * cfg.gps_multipath_std
        xy = poses[:, :2] + noise
        z_true = self.world.terrain.elevation(poses[:, :2])
        alt_std = cfg.gps_altitude_std * np.sqrt(cfg.gps_reference_satellites / safe)
        alt = z_true + cfg.gps_base_altitude + alt_std * rng.standard_normal(n)
        if np.count_nonzero(fix) == n:  # every robot has a fix: nothing to blank out
            return fix, xy, var, alt, sats
        return (
            fix,
            np.where(fix[:, None], xy, 0.0),
            np.where(fix, var, np.inf),
            np.where(fix, alt, np.nan),
            sats,
        )

    # ------------------------------------------------------------------ range finder
    def _scan(self, poses: np.ndarray, rng: np.random.Generator, active: np.ndarray) -> np.ndarray:
        """Range scans of every robot with a range sensor, in one vectorized cast."""
        n = len(poses)
        if self._grid_scan:
            return self._grid_scan_ranges(poses, rng, active)
        rob = self._ray_robot
        dist = np.empty(len(rob))
        for sel, caster in self._ray_groups:
            dist[sel] = caster.cast(poses, poses[:, :2], self._robot_radii)
        ranges = np.full((n, self.max_beams), np.inf)
        if self._one_ray_per_beam:
            ranges[rob, self._ray_beam] = dist
        else:
            np.minimum.at(ranges, (rob, self._ray_beam), dist)
        out = _noisy_ranges(ranges, self.range_std[:, None], self.range_max[:, None], rng)
        out[self._beam_pad] = np.nan
        out[self._no_range | ~active] = np.nan
        return out

    def _grid_scan_ranges(
        self, poses: np.ndarray, rng: np.random.Generator, active: np.ndarray
    ) -> np.ndarray:
        """:meth:`_scan` when every robot has the same laser: no scatter, scalar noise/range."""
        n = len(poses)
        ranges = self._ray_groups[0][1].cast(poses, poses[:, :2], self._robot_radii)
        ranges = ranges.reshape(n, self.max_beams)
        out = rng.standard_normal(ranges.shape)  # then as _noisy_ranges, in one pass
        noisy_ranges_into(out, ranges, float(self.range_std[0]), float(self.range_max[0]))
        if np.count_nonzero(active) < n:
            out[~active] = np.nan
        return out

    # ------------------------------------------------------------------ camera
    def camera_frame(
        self, poses: np.ndarray, rng: np.random.Generator, mask: np.ndarray
    ) -> tuple[list[list[tuple[str, int, float, float]]], CameraSightings]:
        """Objects of interest and robots in the camera's view, bearing quantized to pixels.

        Returns the per-robot ``(kind, id, bearing, noisy range)`` lists and the
        same sightings as arrays (:class:`CameraSightings`).
        """
        cfg = self.cfg
        n = len(poses)
        ooi = self.world.layout.ooi_centers
        targets = np.concatenate([ooi, poses[:, :2]], axis=0)
        kinds, ids, pair_i, pair_j = self._camera_pairs(len(ooi), n)
        fov = np.deg2rad(cfg.camera_fov_deg)
        px = fov / cfg.camera_width_px
        out: list[list[tuple[str, int, float, float]]] = [[] for _ in range(n)]
        if np.count_nonzero(mask) < n:
            pair_i, pair_j = self._masked_pairs(mask, pair_i, pair_j)
        d = targets[pair_j] - poses[pair_i, :2]
        dist = np.hypot(d[:, 0], d[:, 1])
        bearing = wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - poses[pair_i, 2])
        cand = (dist < cfg.camera_max_range) & (np.abs(bearing) <= fov / 2) & (dist > 1e-6)
        cand = cand.nonzero()[0]
        if len(cand) == 0:
            return out, _NO_SIGHTINGS
        obs_i, tgt_j, dist, bearing = pair_i[cand], pair_j[cand], dist[cand], bearing[cand]
        d = d[cand]
        # d is target - origin and dist > 1e-6 its length: the unit line of sight directly.
        visible = self._sight_clear(poses[obs_i, :2], d / dist[:, None], dist)
        pixel = np.rint(bearing / px)  # np.round to 0 decimals
        measured = (pixel * px).tolist()
        vis = visible.tolist()
        if np.count_nonzero(visible) < len(vis):
            keep = visible.nonzero()[0]
            sightings = CameraSightings(obs_i[keep], tgt_j[keep],
                                        [b for b, v in zip(measured, vis, strict=True) if v],
                                        d[keep], dist[keep])
        else:
            sightings = CameraSightings(obs_i, tgt_j, measured, d, dist)
        noise = rng.standard_normal(len(dist))  # drawn either way: the same noise stream
        if not self.camera_lists:
            return out, sightings
        rng_noise = dist + cfg.camera_range_std * noise
        for i, j, b, r, v in zip(obs_i.tolist(), tgt_j.tolist(), measured,
                                 rng_noise.tolist(), vis, strict=True):
            if v:
                out[i].append((kinds[j], ids[j], b, max(r, 0.1)))
        return out, sightings

    def _camera_pairs(self, n_ooi: int, n: int):
        """Target kinds and ids, and every (observer, target) pair but a robot and itself."""
        if self._pairs is None or self._pairs[0] != (n_ooi, n):
            kinds = ["ooi"] * n_ooi + ["robot"] * n
            ids = list(range(n_ooi)) + list(range(n))
            obs_i, tgt_j = np.nonzero(np.ones((n, n_ooi + n), dtype=bool))
            keep = ~((tgt_j >= n_ooi) & (tgt_j - n_ooi == obs_i))
            self._pairs = ((n_ooi, n), (kinds, ids, obs_i[keep], tgt_j[keep]))
        return self._pairs[1]

    def _masked_pairs(
        self, mask: np.ndarray, pair_i: np.ndarray, pair_j: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The camera pairs whose observer is in ``mask`` (cached per mask pattern)."""
        key = (mask.tobytes(), id(pair_i))
        if self._masked_key != key:
            keep = mask[pair_i]
            self._masked = (pair_i[keep], pair_j[keep])
            self._masked_key = key
        return self._masked

    def _sight_clear(self, origins: np.ndarray, d: np.ndarray, dist: np.ndarray) -> np.ndarray:
        """Whether nothing static blocks the segments from ``origins`` along unit ``d``."""
        centers, radii, seg_a, seg_b = self._sight_shapes
        # Both ends lie inside the world, so its walls never block. The target itself
        # may be a circle in the scene (an OOI): allow hits at its surface.
        reach = dist - 0.6
        visible = ~circles_block(origins, d, centers, radii, reach)
        if len(seg_a):
            visible &= ray_segments(origins, d, seg_a, seg_b).min(1) >= reach
        return visible

    # ------------------------------------------------------------------ robot detector
    def _detect(
        self, poses: np.ndarray, rng: np.random.Generator, active: np.ndarray
    ) -> Detections:
        """Identity + (range, bearing, orientation) of teammates in view.

        Fox et al.'s model: a robot in view is detected with ``detection_prob``
        (93.3 %) and missed otherwise; when no robot is in view a false positive
        appears with ``false_positive_prob`` (3.5 %), naming a random teammate
        at a random place in the field of view. Noise is Gaussian; for
        ``detection_model="howard"`` the range noise is proportional to range.
        """
        cfg = self.cfg
        n = len(poses)
        can = self.has_detector & active
        fov = math.radians(cfg.detector_fov_deg)  # the same product as np.deg2rad
        rel_xy = poses[None, :, :2] - poses[:, None, :2]  # [i, j] = p_j - p_i
        dist = np.hypot(rel_xy[..., 0], rel_xy[..., 1])
        in_view = can[:, None] & active
        in_view &= self._others(n)
        in_view &= dist <= cfg.detector_range
        oi, tj = np.nonzero(in_view)
        if len(oi):
            # Bearings of the pairs in range only; rel_xy holds their offsets already.
            pair_xy = rel_xy[oi, tj]
            pair_dist = dist[oi, tj]
            bearing = wrap_angle(np.arctan2(pair_xy[:, 1], pair_xy[:, 0]) - poses[oi, 2])
            if fov < 2 * np.pi:  # all bearings lie in [-pi, pi): a full circle sees every one
                keep = np.abs(bearing) <= fov / 2 + 1e-9
                oi, tj, pair_xy, pair_dist, bearing = (
                    oi[keep], tj[keep], pair_xy[keep], pair_dist[keep], bearing[keep]
                )
        if len(oi):
            los = self._sight_clear(
                poses[oi, :2], pair_xy / np.maximum(pair_dist, 1e-9)[:, None], pair_dist
            )
            seen_any = np.zeros(n, dtype=bool)
            seen_any[oi[los]] = True
            detected = rng.random(np.count_nonzero(los)) < cfg.detection_prob
            pick = np.nonzero(los)[0][detected]
            oi, tj, pair_dist, bearing = oi[pick], tj[pick], pair_dist[pick], bearing[pick]
            # False positives for robots with nothing in view.
            fp_obs = np.nonzero(can & ~seen_any & (rng.random(n) < cfg.false_positive_prob))[0]
        else:  # nothing in view (a size-0 detection draw would not touch the generator)
            fp_obs = np.nonzero(can & (rng.random(n) < cfg.false_positive_prob))[0]
            pair_dist = bearing = np.zeros(0)
        if len(oi) + len(fp_obs) == 0:
            return _NO_DETECTIONS  # (draws of size 0 below would not touch the generator)
        true_z = np.stack([pair_dist, bearing, wrap_angle(poses[tj, 2] - poses[oi, 2])], axis=1)
        if len(fp_obs):
            fp_tgt = (fp_obs + rng.integers(1, n, size=len(fp_obs))) % n
            half = min(fov / 2, np.pi)
            fp_z = np.stack(
                [
                    rng.uniform(2 * cfg.robot_radius, cfg.detector_range, len(fp_obs)),
                    rng.uniform(-half, half, len(fp_obs)),
                    rng.uniform(-np.pi, np.pi, len(fp_obs)),
                ],
                axis=1,
            )
            observer = np.concatenate([oi, fp_obs])
            target = np.concatenate([tj, fp_tgt])
            genuine = np.concatenate([np.ones(len(oi), bool), np.zeros(len(fp_obs), bool)])
            z = np.concatenate([true_z, fp_z], axis=0)
        else:  # only true sightings (size-0 false-positive draws consume no randomness)
            observer, target, genuine, z = oi, tj, np.ones(len(oi), bool), true_z
        std = self._detection_std(z[:, 0])
        noisy = z + std * rng.standard_normal(z.shape)
        noisy[:, 0] = np.maximum(noisy[:, 0], 0.05)
        noisy[:, 1:] = wrap_angle(noisy[:, 1:])
        if cfg.detection_model == "camera":
            px = np.deg2rad(cfg.camera_fov_deg) / cfg.camera_width_px
            noisy[:, 1] = np.round(z[:, 1] / px) * px
        cov = np.zeros((len(z), 3, 3))
        believed = self._detection_std(noisy[:, 0])
        if cfg.detection_model == "camera":
            believed[:, 1] = np.deg2rad(cfg.camera_fov_deg) / cfg.camera_width_px / np.sqrt(12)
        cov[:, [0, 1, 2], [0, 1, 2]] = believed**2
        return Detections(observer, target, noisy, cov, genuine)

    def _others(self, n: int) -> np.ndarray:
        """``(n, n)`` mask of (observer, target) pairs of two different robots (cached)."""
        if self._not_self is None or len(self._not_self) != n:
            self._not_self = ~np.eye(n, dtype=bool)
            self._not_self.flags.writeable = False
        return self._not_self

    def _detection_std(self, ranges: np.ndarray) -> np.ndarray:
        """Per-detection standard deviations of (range, bearing, orientation), ``(k, 3)``."""
        cfg = self.cfg
        k = len(ranges)
        std = np.empty((k, 3))
        model = cfg.detection_model
        if model == "howard":
            std[:, 0] = cfg.detection_range_fraction * ranges + 1e-3
        elif model in ("laser", "scan_min"):
            std[:, 0] = cfg.laser_range_std + 0.05  # centre of the robot from its surface
        elif model == "camera":
            std[:, 0] = cfg.camera_range_std
        else:
            std[:, 0] = cfg.detection_range_std
        if model in ("laser", "scan_min"):
            spacing = np.deg2rad(cfg.laser_fov_deg) / max(cfg.laser_beams - 1, 1)
            std[:, 1] = spacing / np.sqrt(12)
        elif model == "camera":
            std[:, 1] = 1e-4  # quantization is applied separately
        else:
            std[:, 1] = cfg.detection_bearing_std
        std[:, 2] = cfg.detection_orientation_std
        return std
