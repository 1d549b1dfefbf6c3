"""Observation builder: what a robot knows (its belief and its own readings) as one vector.

Layout of an agent's observation (float32, every entry clipped to [-10, 10]):

=====================  ==========================  ===========================================
block                  size                        content
=====================  ==========================  ===========================================
belief                 ``belief_size``             the estimator backend's features, zero-padded
                                                   (EKF: ``backends.base.gaussian_features``; MLE:
                                                   the same 10 plus the estimated relative poses
                                                   of the K nearest teammates, 6 per slot, see
                                                   ``coop_loc_env.backends.mle``; MCL: 48
                                                   values, the same 10 first, then particle
                                                   statistics and histograms, layout in
                                                   ``mcl.filter.belief_feature_names``)
gps                    2                           fix held (0/1), satellites in view / 12, as of
                                                   the last DGPS reading (also one with none)
inclinometer           2                           last pitch and roll (rad)
range                  ``laser_obs_bins``          min-pooled ranges / max range (1 = nothing)
detections             ``6 * max_detections_obs``  per slot, nearest first: present, range /
                                                   detector range, cos/sin bearing, cos/sin
                                                   orientation
last action            2                           the normalized action applied last step
teammates (optional)   11                          ``teammate_obs``: own GPS receiver (0/1);
                                                   then for the nearest teammate with GPS and
                                                   the nearest one without (by the estimates
                                                   the team shares): present, cos/sin bearing
                                                   in the robot's estimated frame, distance /
                                                   detector range, log10 position std
map patch (optional)   ``3 * map_patch_obs**2``    egocentric team-map patch (``map_patch_obs``
                                                   cells a side, ``map_resolution`` m apart,
                                                   axis 0 forward, axis 1 left, row-major),
                                                   three channels one after the other:
                                                   elevation minus the robot's own elevation
                                                   estimate (m, 0 where unmapped), mapped
                                                   (0/1), object of interest marked (0/1)
privileged (optional)  4                           true x/W*2-1, y/H*2-1, cos, sin heading
=====================  ==========================  ===========================================

Each row of the table is an observation block (:mod:`coop_loc_env.obs_blocks`),
registered here under the name ``belief``, ``gps``, ``inclinometer``, ``range``,
``detections``, ``last_action``, ``teammates``, ``map_patch`` and ``privileged``;
the config's ``extra_obs_blocks`` follow them. The agent's own index is not in the
observation, so one policy can be shared by interchangeable robots.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from gymnasium import spaces

from coop_loc_env._step_kernels import pack_observations, pool_scans
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.obs_blocks import (
    CORE_BLOCKS,
    OBS_LIMIT,
    ObsBlock,
    ObsInputs,
    ObsSetup,
    block_names,
    make_block,
    register_obs_block,
)
from coop_loc_env.records import Readings

__all__ = ["OBS_LIMIT", "ObservationBuilder", "teammate_features"]


class ObservationBuilder:
    """Keeps each robot's latched sensor features and assembles the observation blocks.

    ``names`` / ``size``: the vector's entries; ``space``: the observation space (the
    vector's ``Box``, or with ``obs_format="dict"`` a ``Dict`` of the vector and the
    entry blocks); ``blocks``: every block, in order.
    """

    def __init__(self, cfg: ScenarioConfig, belief_size: int, belief_names: tuple[str, ...],
                 world=None):
        self.cfg = cfg
        self.belief_size = belief_size
        n = cfg.n_robots
        # The latched features side by side, in observation order, so that one copy
        # moves them all: gps (2), incl (2), range bins, detections; each a view.
        self._latched = np.zeros((n, 4 + cfg.laser_obs_bins + 6 * cfg.max_detections_obs))
        self._bind_views()
        names = block_names(cfg)
        repeated = sorted({b for b in names if names.count(b) > 1})
        if repeated:
            raise ValueError(f"observation block(s) {repeated} listed twice (extra_obs_blocks "
                             f"adds to {list(names[:len(names) - len(cfg.extra_obs_blocks)])})")
        setup = ObsSetup(cfg, belief_size, tuple(belief_names), world, self)
        self.blocks = [make_block(name, setup) for name in names]
        self.vector_blocks = [b for b in self.blocks if b.entry is None]
        self.entry_blocks = [b for b in self.blocks if b.entry is not None]
        if self.entry_blocks and cfg.obs_format != "dict":
            raise ValueError(f"observation block {self.entry_blocks[0].name!r} is a dict "
                             "entry: it needs obs_format='dict'")
        self.names = [entry for b in self.vector_blocks for entry in b.names]
        self.size = len(self.names)
        self.vector_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(self.size,),
                                       dtype=np.float32)
        self.space = self.vector_space
        if cfg.obs_format == "dict":
            self.space = spaces.Dict({"vector": self.vector_space,
                                      **{b.entry: b.space() for b in self.entry_blocks}})
        # Only belief, latched features and the last action: the compiled pack fills them.
        self._plain = names == CORE_BLOCKS and (
            self.size == belief_size + self._latched.shape[1] + 2)
        self.range[:] = 1.0
        self._det_written = False

    def _bind_views(self) -> None:
        """``gps``, ``incl``, ``range`` and ``det``: column blocks of ``_latched``."""
        bins = self.cfg.laser_obs_bins
        self.gps = self._latched[:, 0:2]
        self.incl = self._latched[:, 2:4]
        self.range = self._latched[:, 4 : 4 + bins]
        self.det = self._latched[:, 4 + bins :]

    @property
    def latched(self) -> np.ndarray:
        """The latched sensor features ``(n, 4 + bins + 6 k)``: gps, incl, range, det."""
        return self._latched

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for key in ("gps", "incl", "range", "det"):  # views: rebuilt on unpickling
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind_views()

    def reset(self) -> None:
        """Forget latched readings (start of an episode)."""
        self.gps[:] = 0.0
        self.incl[:] = 0.0
        self.range[:] = 1.0
        self.det[:] = 0.0
        self._det_written = False
        for block in self.blocks:
            block.reset()

    @property
    def latched_pitch(self) -> np.ndarray:
        """Each robot's last inclinometer pitch ``(n,)`` (a view; 0 before any reading)."""
        return self.incl[:, 0]

    def ingest(self, readings: Readings, max_range: np.ndarray) -> None:
        """Latch the sensor features of one env step.

        The GPS features are refreshed on every step the DGPS receivers report,
        also when none of them sees a satellite (the fix is then lost).
        """
        cfg = self.cfg
        if readings.fired.gps:  # DGPS
            self.gps[:, 0] = readings.gps_mask
            self.gps[:, 1] = readings.satellites / 12.0
        m = readings.inclinometer_mask
        if np.count_nonzero(m):
            self.incl[m, 0] = readings.pitch[m]
            self.incl[m, 1] = readings.roll[m]
        m = readings.range_mask
        fired = np.count_nonzero(m)
        if fired:  # each scanning robot's row pooled on its own (the others keep theirs)
            ranges = readings.ranges
            pool_scans(ranges, np.asarray(max_range, dtype=float),
                       _pool_starts(ranges.shape[1], cfg.laser_obs_bins), m, self.range)
        self._latch_detections(readings)

    def _latch_detections(self, readings: Readings) -> None:
        cfg = self.cfg
        det = readings.detections
        if self._det_written:
            self.det[:] = 0.0
            self._det_written = False
        if len(det):
            self._det_written = True
            order = np.lexsort((det.z[:, 0], det.observer)).tolist()
            observer, z = det.observer.tolist(), det.z.tolist()
            slot = [0] * cfg.n_robots
            for k in order:
                i = observer[k]
                s = slot[i]
                if s >= cfg.max_detections_obs:
                    continue
                r, b, o = z[k]
                self.det[i, 6 * s : 6 * s + 6] = (
                    1.0, r / cfg.detector_range, math.cos(b), math.sin(b), math.cos(o), math.sin(o)
                )
                slot[i] = s + 1

    def observe_all(self, x: ObsInputs) -> np.ndarray | list[dict[str, np.ndarray]]:
        """Every robot's observation: the vectors ``(n, size)``, or with
        ``obs_format="dict"`` one dict per robot."""
        vector = self.vectors(x)
        if not self.entry_blocks:
            return vector
        n = len(vector)
        entries = {}
        for block in self.entry_blocks:
            out = np.empty((n, *block.space().shape), dtype=np.float32)
            block.observe(x, out)
            entries[block.entry] = out
        keys = list(entries)
        return [{"vector": v, **dict(zip(keys, rows, strict=True))}
                for v, *rows in zip(vector, *entries.values(), strict=True)]

    def vectors(self, x: ObsInputs) -> np.ndarray:
        """The observation vectors of all robots ``(n, size)`` float32, clipped."""
        belief = x.belief
        n = len(belief)
        obs = np.empty((n, self.size), dtype=np.float32)
        if self._plain and belief.shape[1] <= self.belief_size and x.last_action.shape[1] == 2:
            pack_observations(belief, self._latched, x.last_action, self.belief_size, OBS_LIMIT,
                              obs)  # the blocks in one pass
            return obs
        start = 0
        for block in self.vector_blocks:  # each block cast to float32 into its columns
            block.observe(x, obs[:, start : start + block.size])
            start += block.size
        np.maximum(obs, -OBS_LIMIT, out=obs)
        return np.minimum(obs, OBS_LIMIT, out=obs)

    def build_all(
        self,
        belief: np.ndarray,
        last_action: np.ndarray,
        true_poses: np.ndarray,
        map_patch: np.ndarray | None = None,
        teammates: np.ndarray | None = None,
    ) -> np.ndarray:
        """Observation vectors ``(n, size)`` from belief features ``(n, b)`` without an
        env: ``map_patch`` ``(n, 3, S, S)`` is required when ``map_patch_obs = S > 0``,
        ``teammates`` (:func:`teammate_features`) when ``teammate_obs`` is on."""
        cfg = self.cfg
        if cfg.teammate_obs and teammates is None:
            raise ValueError("teammates is required when teammate_obs is on, got None")
        if cfg.map_patch_obs and map_patch is None:
            raise ValueError("map_patch is required when map_patch_obs > 0, got None")
        x = ObsInputs(belief, last_action, true_poses, np.zeros((len(belief), 3)),
                      np.zeros((len(belief), 3, 3)), np.ones(len(belief), dtype=bool))
        x.shared("teammates", lambda: teammates)
        x.shared("map_patch", lambda: map_patch)
        return self.vectors(x)


@register_obs_block("belief")
class BeliefBlock(ObsBlock):
    """The estimator backend's belief features, zero-padded to ``belief_size``."""

    def __init__(self, setup: ObsSetup) -> None:
        pad = setup.belief_size - len(setup.belief_names)
        super().__init__(setup, [*setup.belief_names, *(f"belief_pad_{i}" for i in range(pad))])

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        width = x.belief.shape[1]
        out[:, :width] = x.belief
        out[:, width:] = 0.0


class LatchedBlock(ObsBlock):
    """A block of the builder's latched sensor features (``view``: its attribute name)."""

    view = ""

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        out[:] = getattr(self.setup.builder, self.view)


@register_obs_block("gps")
class GPSBlock(LatchedBlock):
    """Fix held (0/1) and satellites in view / 12, as of the last DGPS reading."""

    view = "gps"

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, ["gps_fix", "gps_satellites"])


@register_obs_block("inclinometer")
class InclinometerBlock(LatchedBlock):
    """The last pitch and roll (rad)."""

    view = "incl"

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, ["pitch", "roll"])


@register_obs_block("range")
class RangeBlock(LatchedBlock):
    """Min-pooled ranges / max range (1 = nothing), ``laser_obs_bins`` of them."""

    view = "range"

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, [f"range_bin_{i}" for i in range(setup.cfg.laser_obs_bins)])


DETECTION_FIELDS = ("present", "range", "cos_bearing", "sin_bearing", "cos_orient",
                    "sin_orient")


@register_obs_block("detections")
class DetectionsBlock(LatchedBlock):
    """Per slot, nearest first: the 6 :data:`DETECTION_FIELDS`."""

    view = "det"

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, [f"det{k}_{f}" for k in range(setup.cfg.max_detections_obs)
                                 for f in DETECTION_FIELDS])


@register_obs_block("last_action")
class LastActionBlock(ObsBlock):
    """The normalized action applied last step."""

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, ["last_v", "last_w"])

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        out[:] = x.last_action


@register_obs_block("teammates")
class TeammatesBlock(ObsBlock):
    """The nearest GPS and no-GPS teammates' shared estimates (:func:`teammate_features`)."""

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, ["team_own_gps"] + [
            f"team_{kind}_{f}" for kind in ("gps", "nogps")
            for f in ("present", "cos_bearing", "sin_bearing", "range", "log10_std")])

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        out[:] = x.shared("teammates", lambda: teammate_features(
            x.est_mean, x.est_cov, x.env.sensors.has_gps, x.active,
            self.setup.cfg.detector_range))


@register_obs_block("map_patch")
class MapPatchBlock(ObsBlock):
    """The egocentric team-map patch: elevation, mapped, object channels."""

    def __init__(self, setup: ObsSetup) -> None:
        size = setup.cfg.map_patch_obs
        super().__init__(setup, [f"map_{channel}_{u}_{v}"
                                 for channel in ("elev", "mapped", "object")
                                 for u in range(size) for v in range(size)])

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        patch = x.shared("map_patch", lambda: x.env.mapper.patches(
            x.est_mean, self.setup.cfg.map_patch_obs))
        out[:] = np.asarray(patch).reshape(len(out), -1)


@register_obs_block("privileged")
class PrivilegedBlock(ObsBlock):
    """The true pose (for baselines): x/W*2-1, y/H*2-1, cos, sin heading."""

    def __init__(self, setup: ObsSetup) -> None:
        super().__init__(setup, ["true_x", "true_y", "true_cos_heading", "true_sin_heading"])

    def observe(self, x: ObsInputs, out: np.ndarray) -> None:
        w, h = self.setup.cfg.world_size
        px, py, th = x.true_poses.T
        out[:] = np.stack([px / w * 2 - 1, py / h * 2 - 1, np.cos(th), np.sin(th)], 1)



def teammate_features(
    mean: np.ndarray, cov: np.ndarray, has_gps: np.ndarray, live: np.ndarray, scale: float
) -> np.ndarray:
    """``(n, 11)`` per robot: own GPS flag, then for the nearest live teammate with GPS and
    the nearest without: present, cos/sin bearing in the robot's estimated frame, distance
    / ``scale``, log10 RMS position std (the layout of the observation's teammates block).

    Computed from the estimates the team shares (``mean (n, 3)``, ``cov (n, 3, 3)``),
    never the true poses.
    """
    n = len(mean)
    out = np.zeros((n, 11))
    out[:, 0] = has_gps
    rel = mean[None, :, :2] - mean[:, None, :2]  # rel[i, j]: from i to j
    dist = np.hypot(rel[..., 0], rel[..., 1])
    bearing = np.arctan2(rel[..., 1], rel[..., 0]) - mean[:, 2:3]
    log_std = np.log10(np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 1e-12)))
    mate = live[None, :] & ~np.eye(n, dtype=bool)
    for col, kind in ((1, has_gps), (6, ~has_gps)):
        d = np.where(mate & kind[None, :], dist, np.inf)
        j = np.argmin(d, axis=1)
        rows = np.arange(n)
        present = np.isfinite(d[rows, j])
        b = bearing[rows, j]
        block = np.stack([np.ones(n), np.cos(b), np.sin(b), dist[rows, j] / scale,
                          log_std[j]], axis=1)
        out[:, col : col + 5] = np.where(present[:, None], block, 0.0)
    return out


@functools.lru_cache(maxsize=64)
def _pool_starts(beams: int, bins: int) -> np.ndarray:
    return np.minimum(np.floor(np.linspace(0, beams, bins + 1)[:-1]).astype(int), beams - 1)
