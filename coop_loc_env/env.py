"""The PettingZoo parallel environment: a team of robots that localize cooperatively."""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from coop_loc_env.actions import ACTION_TOLERANCE, check_action
from coop_loc_env.backends.base import GAUSSIAN_FEATURE_NAMES, make_backends
from coop_loc_env.camera import CameraPipeline
from coop_loc_env.config import ScenarioConfig
from coop_loc_env.depth_from_motion import CameraRecord, DepthFromMotion
from coop_loc_env.mapping import TeamMapper
from coop_loc_env.obs_blocks import ObsInputs
from coop_loc_env.observations import ObservationBuilder
from coop_loc_env.records import Beliefs, JoinedSampler, Readings, StepRecord
from coop_loc_env.rewards import RewardInputs, RewardTerms, sum_terms
from coop_loc_env.scenarios import make_config, scenario_hooks
from coop_loc_env.sensors import SensorSuite
from coop_loc_env.world import World
from estimators.geometry import wrap_angle


class CoopLocParallelEnv(ParallelEnv):
    """Multi-robot cooperative localization as a PettingZoo ``ParallelEnv``.

    Agents ``robot_0 .. robot_{n-1}`` drive skid-steer robots with normalized
    actions ``(linear velocity, turn rate)`` in ``[-1, 1]^2``. Each robot's
    sensors feed its estimator; its observation is its belief plus its own
    readings (see :mod:`coop_loc_env.observations`; with ``obs_format="dict"``
    a ``Dict`` of that vector plus the belief's modes, and the belief as a map,
    :mod:`coop_loc_env.belief_map`); its reward is the
    weighted negative true localization error, plus the weighted number of
    drivable cells it was first in the team to cover at its *true* pose
    (``reward_coverage_weight``; belief drift earns nothing), minus
    ``collision_penalty`` for every step it spends touching an obstacle, a wall
    or another robot, and the tip-over penalty (terms in ``info["reward_<term>"]``).
    The team terrain map (:mod:`coop_loc_env.mapping`) is updated every step
    from the robots' beliefs, inclinometers and DGPS altitudes; camera ranges
    come from depth from motion (:mod:`coop_loc_env.depth_from_motion`).

    Args:
        scenario: a registered scenario name (:func:`coop_loc_env.list_scenarios`).
        render_mode: ``None``, ``"rgb_array"`` or ``"human"``.
        **overrides: any :class:`~coop_loc_env.config.ScenarioConfig` field,
            e.g. ``n_robots=4``, ``estimator="ekf"``, ``max_cycles=200``.

    Infos (per agent): ``true_pose``, ``est_pose`` (x, y, heading), ``pose_cov``
    (3x3), ``position_error`` (m), ``heading_error`` (rad), the reward terms as
    ``reward_localization``, ``reward_coverage``, ``reward_collision`` and
    ``reward_tip_over`` (and also as the dict ``reward_terms`` with the config's
    ``reward_terms_dict=True``), ``gps_fix``, ``satellites``, ``collisions``
    (new contacts this step), ``in_contact`` (touched something this step: the
    collision penalty applies), ``tipped_over``, ``new_cells`` (team-map cells
    this robot newly mapped this step, at its estimated pose), ``covered_cells``
    (drivable cells this robot was first to cover this step, at its true pose:
    the coverage reward counts these), ``coverage`` (fraction of the drivable
    area the team has mapped) and ``map_rmse`` (m, team map vs true height field
    over mapped cells), plus the estimators' own entries (MCL:
    ``particle_spread``, ``n_particles``, ``detections_used``), NaN for robots
    whose estimator does not report them: every agent of a team has the same
    keys. By default every value is a number or a fixed-shape array (what
    TorchRL and BenchMARL stack); ``info_keys=("position_error", ...)`` keeps
    only the named entries (an unknown name raises ``ValueError`` at reset).
    """

    metadata = {
        "name": "coop_loc_v0",
        "render_modes": ["human", "rgb_array"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        scenario: str = "outdoor_terrain",
        render_mode: str | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, "
                f"got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.scenario = scenario
        self.config: ScenarioConfig = make_config(scenario, **overrides)
        self.scenario_hooks = scenario_hooks(scenario)
        cfg = self.config
        self.possible_agents = [f"robot_{i}" for i in range(cfg.n_robots)]
        self.agent_name_mapping = {a: i for i, a in enumerate(self.possible_agents)}
        self.world = World(cfg)
        self._speed_limits = np.stack([self.world.max_speed, self.world.max_turn_rate], axis=1)
        # Depth from motion reads the camera's sightings, not its noisy-range lists.
        self.sensors = SensorSuite(cfg, self.world, camera_lists=False)
        self.backends = make_backends(cfg, self.world)
        self.mapper = TeamMapper(cfg, self.world)
        self.reward_terms = RewardTerms(cfg)
        self.depth = DepthFromMotion(cfg, len(self.world.layout.ooi_centers))
        self.camera = CameraPipeline(self.sensors, self.depth, self.world.layout.ooi_centers)
        belief_size = max(b.feature_size for b in self.backends)
        belief_names = GAUSSIAN_FEATURE_NAMES if belief_size == len(GAUSSIAN_FEATURE_NAMES) else ()
        for b in self.backends:
            if b.feature_size == belief_size and b.feature_names:
                belief_names = tuple(b.feature_names)
        self.observations = ObservationBuilder(cfg, belief_size, belief_names, self.world)
        self._one_backend = len(self.backends) == 1 and np.array_equal(
            self.backends[0].robots, np.arange(cfg.n_robots)
        )
        self._observation_space = self.observations.space
        self._action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._np_random: np.random.Generator | None = None
        self._np_random_seed: int | None = None
        self._renderer = None
        self._rows_key: tuple[str, ...] | None = None
        self._rows: list[int] = []
        self.agents: list[str] = []
        self._reset_state()

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> spaces.Box | spaces.Dict:
        """The observation space of ``agent`` (the same object on every call): a ``Box``, or
        with ``obs_format="dict"`` a ``Dict`` (:mod:`coop_loc_env.belief_map`)."""
        self._check_agent_name(agent)
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Box:
        """The action space of ``agent``: ``Box(-1, 1, (2,))`` (the same object every call)."""
        self._check_agent_name(agent)
        return self._action_space

    def _check_agent_name(self, agent: str) -> None:
        if agent not in self.agent_name_mapping:
            raise ValueError(f"unknown agent {agent!r}; agents are {self.possible_agents}")

    @property
    def np_random(self) -> np.random.Generator:
        """The episode's random generator (seeded by :meth:`reset`)."""
        if self._np_random is None:
            self._np_random, self._np_random_seed = seeding.np_random()
        return self._np_random

    @property
    def beliefs(self) -> Beliefs:
        """The team's beliefs after the last step or reset (:class:`~coop_loc_env.records.
        Beliefs`: every robot's mean, covariance, belief features and, for particle
        filters, its particle set); shared arrays: copy before changing them."""
        return self._beliefs

    @property
    def estimated_poses(self) -> np.ndarray:
        """Current belief means of all robots ``(n, 3)`` (a copy)."""
        return self._beliefs.mean.copy()

    @property
    def estimated_covariances(self) -> np.ndarray:
        """Current belief covariances of all robots ``(n, 3, 3)`` (a copy)."""
        return self._beliefs.cov.copy()

    @property
    def last_readings(self) -> Readings | None:
        """The sensor readings of the last step (``None`` right after :meth:`reset`); the
        camera's part is computed when first read."""
        return self._last_readings

    @property
    def active(self) -> np.ndarray:
        """``(n,)``: the robots still in the episode (the env's array: do not change it)."""
        return self._active

    @property
    def tipped(self) -> np.ndarray:
        """``(n,)``: the robots that tipped over in this episode (the env's array)."""
        return self._tipped

    @property
    def new_cells(self) -> np.ndarray:
        """``(n,)``: team-map cells each robot newly mapped in the last step."""
        return self._new_cells

    @property
    def covered_cells(self) -> np.ndarray:
        """``(n,)``: drivable cells each robot was first to cover in the last step."""
        return self._covered_cells

    def observation_inputs(self) -> ObsInputs:
        """What the observation blocks read now (:class:`~coop_loc_env.obs_blocks.
        ObsInputs`): the beliefs, the last action, the true poses, the active robots."""
        beliefs = self._beliefs
        return ObsInputs(beliefs.features, self._last_action, self.world.poses, beliefs.mean,
                         beliefs.cov, self._active, self)

    @property
    def step_count(self) -> int:
        """Steps taken in this episode."""
        return self._step_count

    @property
    def terrain_map(self):
        """The team terrain map (:class:`estimators.terrain_map.TerrainMap`) built so far."""
        return self.mapper.map

    def camera_readings(self, agent: str) -> list[CameraRecord]:
        """What ``agent``'s camera saw in the last step (empty when it took no frame).

        Each :class:`~coop_loc_env.depth_from_motion.CameraRecord` holds the
        object's kind and id, its pixel-quantized bearing and a depth-from-motion
        range with its standard deviation.
        """
        self._check_agent_name(agent)
        readings = self._last_readings
        if readings is None or readings.camera_frame is None:
            return []  # no frame this step
        return list(readings.camera_frame.get().records[self.agent_name_mapping[agent]])

    def mark_object(self, agent: str, x: float, y: float, radius: float = 0.0) -> int:
        """``agent`` reports an object of interest at world ``(x, y)`` to the team map.

        Returns the number of map cells newly marked.
        """
        self._check_agent_name(agent)
        return self.mapper.map.mark_object(float(x), float(y), radius)

    # ------------------------------------------------------------------ reset
    def _reset_state(self) -> None:
        n = self.config.n_robots
        self._step_count = 0
        self._active = np.ones(n, dtype=bool)
        self._tipped = np.zeros(n, dtype=bool)
        self._last_action = np.zeros((n, 2))
        self._beliefs = Beliefs(np.arange(n), np.zeros((n, 3)),
                                np.repeat(np.eye(3)[None], n, axis=0),
                                np.zeros((n, self.observations.belief_size)))
        self._last_readings: Readings | None = None
        self._new_cells = np.zeros(n, dtype=np.int64)
        self._covered_cells = np.zeros(n, dtype=np.int64)

    def reset(
        self, seed: int | None = None, options: dict | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        """Start an episode; ``seed`` makes it reproducible."""
        if seed is not None:
            self._np_random, self._np_random_seed = seeding.np_random(seed)
        rng = self.np_random
        self._reset_state()
        self.world.reset(rng)
        self.scenario_hooks.reset_world(self, rng)
        for backend in self.backends:
            backend.reset(self.world.poses, rng)
        self.camera.reset(self.world.poses, rng)
        self.observations.reset()
        self._beliefs = self._gather_beliefs()
        self.reward_terms.reset(RewardInputs.at_start(self._beliefs.cov, self._active, self))
        self.mapper.reset(self.world.poses, self._beliefs.mean, self._beliefs.cov)
        self.agents = list(self.possible_agents)
        zeros = np.zeros(self.config.n_robots)
        infos = self._infos(zeros, np.zeros(self.config.n_robots, dtype=int))[0]
        obs = self._observe_all(self.agents)
        if self.render_mode == "human":
            self.render()
        return obs, infos

    # ------------------------------------------------------------------ step
    def step(self, actions: dict[str, Any]):
        """Apply one action per live agent; returns PettingZoo's five dicts.

        Actions of agents already done (terminated or truncated) are ignored,
        unchecked: a trainer that sends an action for every agent of the team
        (TorchRL with ``done_on_any=False``) works. Every live agent must act.
        """
        act = self._validate_actions(actions)
        live = list(self.agents)
        out = self.step_core(act)
        infos, rewards = self._infos(
            out.tipped_now, out.new_contacts, live, in_contact=out.in_contact, step=out,
        )
        truncate = out.truncated
        if truncate or np.count_nonzero(self._active) < self._active.size:
            active = self._active.tolist()
            terminations = {a: not active[self.agent_name_mapping[a]] for a in live}
            truncations = dict.fromkeys(live, truncate)
            going_on = [a for a in live if not (terminations[a] or truncate)]
        else:  # every robot is still in and the episode goes on: so does every live agent
            terminations, truncations = dict.fromkeys(live, False), dict.fromkeys(live, False)
            going_on = live
        obs = self._observe_all(live)
        self.agents = going_on
        if self.render_mode == "human":
            self.render()
        return obs, rewards, terminations, truncations, infos

    def step_core(self, act: np.ndarray) -> StepRecord:
        """The step's array core, shared with :func:`coop_loc_env.vector_env`: moves the
        world by the checked actions ``(n, 2)`` (rows of robots already out are zeros),
        reads the sensors, updates the beliefs, the team map and the reward terms, and
        returns the step's values as one :class:`StepRecord` (observations are built
        afterwards, from the env's state)."""
        cfg = self.config
        rng = self.np_random
        # (n, 2): commanded V and w. Only live agents act, and every live agent is active:
        # the rows of tipped-over robots are zeros, so they stand still.
        cmd = act * self._speed_limits
        physics = self.world.step(cmd[:, 0], cmd[:, 1], self._active, rng, idle_zeroed=True)
        # The wheel encoders see the command at every substep; the camera's frame is
        # queued (computed when read).
        readings = self.sensors.read(self._step_count, physics.poses, cmd, rng, self._active,
                                     touching=physics.touching, camera=self.camera.add_step)
        self._last_readings = readings
        for backend in self.backends:
            backend.step(readings, self._active)
        self._beliefs = beliefs = self._gather_beliefs()
        self.observations.ingest(readings, self.sensors.range_max)
        self._new_cells = self.mapper.step(readings, beliefs, self._active,
                                           self.observations.latched_pitch,
                                           true_poses=physics.poses)
        self._covered_cells = self.mapper.last_covered_cells
        self._last_action = act
        self._step_count += 1

        self._tipped |= physics.tipped
        if cfg.tip_over_terminates:
            self._active &= ~physics.tipped
        truncate = self._step_count >= cfg.max_cycles
        tipped_now = physics.tipped.astype(float)
        poses = self.world.poses.copy()
        est = self._beliefs.mean.copy()
        cov = self._beliefs.cov.copy()
        diff = est - poses
        err_xy = np.hypot(diff[:, 0], diff[:, 1])
        err_th = np.abs(wrap_angle(diff[:, 2]))
        terms = self._reward_terms(err_xy, err_th, physics.in_contact, tipped_now, cov)
        return StepRecord(poses, est, cov, err_xy, err_th, terms, sum_terms(terms), tipped_now,
                          physics.new_contacts, physics.in_contact, truncate)

    def _validate_actions(self, actions: dict[str, Any]) -> np.ndarray:
        """Check every action before touching any state; returns ``(n, 2)`` floats."""
        if not self.agents:
            when = "on a finished episode" if self._np_random is not None else "before reset()"
            raise ValueError(f"step() called {when}: call reset() first")
        if not isinstance(actions, dict):
            raise ValueError(
                f"actions must be a dict agent -> action, got {type(actions).__name__}"
            )
        keys = list(actions)
        if keys == self.agents:  # the usual case: every live agent, in order
            rows = None if len(keys) == self.config.n_robots else self._rows_of(keys)
        else:
            unknown = [a for a in actions if a not in self.agent_name_mapping]
            if unknown:
                raise ValueError(f"unknown agent(s) {unknown} in actions; agents: {self.agents}")
            if len(actions) > len(self.agents):  # ignore actions of agents already done
                live = set(self.agents)
                actions = {a: v for a, v in actions.items() if a in live}
            missing = [a for a in self.agents if a not in actions]
            if missing:
                raise ValueError(f"missing actions for agents {missing}")
            rows = [self.agent_name_mapping[a] for a in actions]
        values = list(actions.values())
        if any(type(v) is not np.ndarray or v.dtype.kind not in "fiu" for v in values):
            for agent, action in actions.items():  # lists, or arrays of strings, bools...
                check_action(agent, action)
        try:
            stacked = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            stacked = None
        # The largest magnitude: NaN (which fails every comparison) if any entry is NaN.
        peak = np.abs(stacked).max() if stacked is not None and stacked.size else 0.0
        if stacked is None or stacked.shape != (len(actions), 2) or not (
            peak <= 1.0 + ACTION_TOLERANCE
        ):
            for agent, action in actions.items():  # find and name the bad one
                check_action(agent, action)
        if rows is None:
            out = stacked
        else:
            out = np.zeros((self.config.n_robots, 2))
            out[rows] = stacked
        if peak > 1.0:  # within the tolerance: clip to the box
            np.maximum(out, -1.0, out=out)
            np.minimum(out, 1.0, out=out)
        return out

    def _rows_of(self, agents: list[str]) -> list[int]:
        """Robot indices of ``agents`` (cached for the current list of live agents)."""
        key = tuple(agents)
        if self._rows_key != key:
            self._rows_key = key
            self._rows = [self.agent_name_mapping[a] for a in agents]
        return self._rows

    # ------------------------------------------------------------------ beliefs, obs, infos
    def _gather_beliefs(self) -> Beliefs:
        """The team's beliefs: each backend's, in robot order (features zero-padded)."""
        if self._one_backend:  # one estimator for the whole team, robots in order
            return self.backends[0].beliefs()  # (ObservationBuilder pads its features)
        n = self.config.n_robots
        mean, cov = np.zeros((n, 3)), np.repeat(np.eye(3)[None], n, axis=0)
        features = np.zeros((n, self.observations.belief_size))
        samplers = []
        for backend in self.backends:
            part = backend.beliefs()
            mean[part.robots], cov[part.robots] = part.mean, part.cov
            features[part.robots, : part.features.shape[1]] = part.features
            if part.sampler is not None:
                samplers.append(part.sampler)
        return Beliefs(np.arange(n), mean, cov, features,
                       JoinedSampler(samplers) if samplers else None)

    def _observe_all(self, agents: list[str]) -> dict[str, np.ndarray]:
        obs = self.observations.observe_all(self.observation_inputs())
        if len(agents) == len(obs):  # every agent (a live list keeps their order): row views
            return dict(zip(agents, obs, strict=True))
        return {a: obs[self.agent_name_mapping[a]] for a in agents}

    def _infos(
        self,
        tipped: np.ndarray,
        new_contacts: np.ndarray,
        agents: list[str] | None = None,
        in_contact: np.ndarray | None = None,
        step: StepRecord | None = None,
    ) -> tuple[dict[str, dict], dict[str, float]]:
        """Infos and rewards of ``agents`` (all possible agents by default), in that order:
        of the step ``step`` (its errors and reward terms), or of the episode's start."""
        cfg = self.config
        if step is None:  # at reset: the errors and reward terms of the start
            step = self._start_record(tipped, new_contacts, in_contact)
        poses, est, cov = step.true_pose, step.est_pose, step.pose_cov
        err_xy, err_th, terms, totals = step.err_xy, step.err_th, step.terms, step.rewards
        readings = self._last_readings
        extra = self.extra_infos()
        coverage = self.mapper.coverage()
        map_rmse = self.mapper.map_rmse()
        terms_dict = cfg.reward_terms_dict
        keep = cfg.info_keys
        n = cfg.n_robots
        if readings is not None:
            fix, sats = readings.gps_mask.tolist(), readings.satellites.tolist()
        else:
            fix, sats = [False] * n, [0] * n
        touching = [False] * n if in_contact is None else in_contact.tolist()
        columns = zip(
            self.possible_agents, err_xy.tolist(), err_th.tolist(), fix, sats,
            new_contacts.tolist(), touching, self._tipped.tolist(),
            self._new_cells.tolist(), self._covered_cells.tolist(), strict=True,
        )
        if agents is not None and len(agents) < n:  # only the live agents' entries
            every = list(columns)
            columns = [(i, every[i]) for i in self._rows_of(agents)]
        else:
            columns = enumerate(columns)
        infos, rewards = {}, {}
        names = list(terms)
        flat_names = [_flat_reward_key(name) for name in names]
        per_robot = list(zip(*terms.values(), strict=True))  # one tuple of terms per robot
        for i, (agent, exy, eth, gps, nsat, hits, touch, tipped_over, cells,
                covered) in columns:
            rewards[agent] = totals[i]
            values = per_robot[i]
            own_terms = dict(zip(names, values, strict=True)) if terms_dict else None
            info = {
                "true_pose": poses[i],
                "est_pose": est[i],
                "pose_cov": cov[i],
                "position_error": exy,
                "heading_error": eth,
                **dict(zip(flat_names, values, strict=True)),
                "gps_fix": bool(gps),
                "satellites": int(nsat),
                "collisions": int(hits),
                "in_contact": bool(touch),
                "tipped_over": bool(tipped_over),
                "new_cells": int(cells),
                "covered_cells": int(covered),
                "coverage": coverage,
                "map_rmse": map_rmse,
                **extra.get(i, {}),
            }
            if terms_dict:
                info["reward_terms"] = own_terms
            infos[agent] = info if keep is None else _keep_keys(info, keep)
        return infos, rewards

    def _start_record(
        self, tipped: np.ndarray, new_contacts: np.ndarray, in_contact: np.ndarray | None
    ) -> StepRecord:
        """The values of an episode's start (its reward terms computed and advanced)."""
        poses = self.world.poses.copy()  # each agent's info holds rows of fresh copies
        est = self._beliefs.mean.copy()
        cov = self._beliefs.cov.copy()
        diff = est - poses
        err_xy = np.hypot(diff[:, 0], diff[:, 1])
        err_th = np.abs(wrap_angle(diff[:, 2]))
        terms = self._reward_terms(err_xy, err_th, in_contact, tipped, cov)
        return StepRecord(poses, est, cov, err_xy, err_th, terms, sum_terms(terms), tipped,
                          new_contacts, in_contact, False)

    def _reward_terms(
        self,
        err_xy: np.ndarray,
        err_th: np.ndarray,
        in_contact: np.ndarray | None,
        tipped: np.ndarray,
        cov: np.ndarray,
    ) -> dict[str, list[float]]:
        """Every robot's reward terms (:mod:`coop_loc_env.rewards`), each weighted.

        Returns ``{term name: one Python float per robot}``, in the order the
        reward sums them; infos report them as ``reward_<term>`` and
        ``reward_terms``. Runs the terms' compute phase, then their advance phase
        (call once per step).
        """
        x = RewardInputs(err_xy, err_th, in_contact, tipped, cov, self._covered_cells,
                         self._active, self)
        terms = self.reward_terms.compute(x)
        self.reward_terms.advance(x)
        return terms

    def extra_infos(self) -> dict[int, dict]:
        """The estimators' extra info entries per robot, every robot with the same keys.

        In a mixed team a key that only some robots' estimator reports (e.g. MCL's
        ``particle_spread``) is NaN for the others, so every agent's info has the
        same keys (TorchRL stacks them per team).
        """
        extra: dict[int, dict] = {}
        for backend in self.backends:
            for i, entries in backend.extra_info(self.world.poses).items():
                extra.setdefault(int(i), {}).update(entries)
        if not extra:
            return extra
        keys: dict[str, None] = {}
        for entries in extra.values():
            keys.update(dict.fromkeys(entries))
        for i in range(self.config.n_robots):
            entries = extra.setdefault(i, {})
            if len(entries) < len(keys):
                for key in keys:
                    entries.setdefault(key, float("nan"))
        return extra

    # ------------------------------------------------------------------ render
    def render(self, mode: str | None = None) -> np.ndarray | None:
        """Draw the scene: terrain, canopy, obstacles, true/estimated poses with 2-sigma
        ellipses, range rays and detections. ``rgb_array`` returns ``uint8 (H, W, 3)``.

        ``mode`` (for callers of the older ``render(mode)`` API, e.g. RLlib's
        PettingZoo wrappers) must be ``None`` or the env's ``render_mode``.
        """
        if mode is not None and mode != self.render_mode:
            raise ValueError(
                f"render mode {mode!r} differs from the env's render_mode {self.render_mode!r}"
            )
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode=...")
            return None
        if self._renderer is None:
            from coop_loc_env.rendering import Renderer

            self._renderer = Renderer(self)
        frame = self._renderer.draw()
        if self.render_mode == "rgb_array":
            return frame
        self._renderer.show(frame)
        return None

    def close(self) -> None:
        """Release the renderer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state


def _keep_keys(info: dict[str, Any], keep: tuple[str, ...]) -> dict[str, Any]:
    """The entries of ``info`` named in ``keep`` (the config's ``info_keys``), in that order."""
    try:
        return {key: info[key] for key in keep}
    except KeyError as err:
        raise ValueError(
            f"info_keys names {err.args[0]!r}, not an info key of this env; "
            f"its keys: {', '.join(info)}"
        ) from None


@functools.lru_cache(maxsize=64)
def _flat_reward_key(name: str) -> str:
    """The info key of a reward term in the flat form (``reward_<term>``)."""
    return f"reward_{name}"

