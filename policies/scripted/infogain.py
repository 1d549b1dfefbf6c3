"""``infogain``: greedy information seeking for a team of EKF robots.

Every ``replan_every`` steps the team picks, robot by robot (coordinate descent,
``passes`` sweeps), one of a few motion primitives: stand still, or turn to one
of ``n_headings`` world headings and drive straight at full speed. A primitive
is scored by the team's expected uncertainty over the next ``horizon`` seconds
-- the mean over the horizon of ``sum_i log det P_i`` of the robots' position
covariances -- predicted from the beliefs the team shares and the measurements
each candidate motion would bring:

* dead reckoning grows ``P`` by ``q_per_m`` (m^2) per metre driven;
* a robot with GPS gets a fix wherever the known canopy map leaves enough
  satellites (the sensor's satellite model at its mean counts), with the
  sensor's variance;
* two robots within the detector range exchange relative updates at the
  detector rate (times the detection probability); as with the conservative
  (covariance-intersection) fusion, a teammate ``j`` can bring robot ``i`` no
  lower than ``P_j + R(range)``: each detection closes the fraction
  ``fusion_rate`` of the gap between ``P_i`` and the best such bound below it
  (two equally lost robots teach each other nothing).

Ties -- no candidate brings any information within the horizon, as when every
teammate is far away -- are broken by a small cost on the distance from the
candidate's end point to the nearest teammate that could inform the robot (a
GPS-equipped one for a robot without GPS, and the other way round). Between
replans each robot tracks its primitive's heading by its own estimate and
turns away from obstacles its laser sees ahead. The planner reads the beliefs,
the static map (canopies, world bounds) and the robots' hardware, never the
true poses.

Robots that run MCL (particle beliefs) are planned instead by
:class:`~policies.scripted.infogain_mcl.MCLInfoGainPlanner`: expected entropy
reduction over pose hypotheses drawn from their particles, as in active Markov
localization (Fox, Burgard and Thrun); see :mod:`policies.scripted.infogain_mcl`.
"""

from __future__ import annotations

import numpy as np

from estimators.geometry import wrap_angle
from policies.scripted.common import Steering, gps_flags
from policies.scripted.infogain_mcl import MCLInfoGainPlanner
from policies.scripted.view import ViewBuilder

STOP = -1


def _inv2(m: np.ndarray) -> np.ndarray:
    """Inverse of a stack of symmetric 2x2 matrices ``(..., 2, 2)``."""
    a, b, d = m[..., 0, 0], m[..., 0, 1], m[..., 1, 1]
    det = a * d - b * b
    out = np.empty_like(m)
    out[..., 0, 0] = d / det
    out[..., 1, 1] = a / det
    out[..., 0, 1] = out[..., 1, 0] = -b / det
    return out


def _logdet2(m: np.ndarray) -> np.ndarray:
    return np.log(np.maximum(m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] ** 2, 1e-300))


class TeamInfoModel:
    """The planner's model of how the team's position covariances evolve (see module doc)."""

    def __init__(self, env, dt: float, q_per_m: float, fusion_rate: float) -> None:
        cfg = env.config
        self.dt = dt
        self.q_per_m = q_per_m
        self.under_canopy = env.world.layout.under_canopy
        self.gps = gps_flags(env)
        self.det_range = cfg.detector_range
        per_step = cfg.detector_rate * dt * cfg.detection_prob * 2.0  # both robots detect
        self.rel_gain = 1.0 - (1.0 - fusion_rate) ** per_step
        self.range_var = cfg.detection_range_std**2
        self.bearing_var = cfg.detection_bearing_std**2
        self.gps_per_step = cfg.gps_rate * dt
        self.gps_var_num = cfg.gps_std**2 * cfg.gps_reference_satellites
        self.open_sats = 0.5 * sum(cfg.gps_open_sky_satellites)
        self.canopy_sats = 0.5 * sum(cfg.gps_canopy_satellites)

    def cost(self, paths: np.ndarray, cov0: np.ndarray, live: np.ndarray) -> np.ndarray:
        """Mean over the horizon of the team's summed position log det, per candidate.

        Args:
            paths: ``(C, n, T + 1, 2)`` positions of every robot under each candidate,
                index 0 the present.
            cov0: ``(n, 2, 2)`` present position covariances.
            live: ``(n,)`` robots still in the episode.
        """
        c, n, t1, _ = paths.shape
        eye = np.eye(2)
        cov = np.broadcast_to(cov0, (c, n, 2, 2)).copy()
        step = np.hypot(*np.moveaxis(np.diff(paths, axis=2), -1, 0))  # (C, n, T)
        pair = live[:, None] & live[None, :] & ~np.eye(n, dtype=bool)
        gps = self.gps & live
        total = np.zeros(c)
        for t in range(1, t1):
            pos = paths[:, :, t]
            cov = cov + (self.q_per_m * step[:, :, t - 1])[..., None, None] * eye
            rel = pos[:, :, None] - pos[:, None]
            dist = np.hypot(rel[..., 0], rel[..., 1])  # (C, n, n)
            near = (dist < self.det_range) & pair
            if near.any():  # move P_i toward the best P_j + R that is below it
                r = self.range_var + self.bearing_var * dist**2
                target = cov[:, None, :, :, :] + r[..., None, None] * eye  # [c, i, j]
                ld = np.where(near, _logdet2(target), np.inf)
                j = np.argmin(ld, axis=2)
                best = np.take_along_axis(target, j[..., None, None, None], axis=2)[:, :, 0]
                better = np.take_along_axis(ld, j[..., None], axis=2)[..., 0] < _logdet2(cov)
                cov = np.where(better[..., None, None], cov + self.rel_gain * (best - cov), cov)
            info = _inv2(cov)
            if gps.any():
                depth = self.under_canopy(pos.reshape(-1, 2)).reshape(c, n)
                blend = np.clip(depth / 0.5, 0.0, 1.0)  # the receiver's satellite model
                sats = (1 - blend) * self.open_sats + blend * self.canopy_sats
                fix = gps & (sats >= 4)
                w = np.where(fix, self.gps_per_step * sats / self.gps_var_num, 0.0)
                info = info + w[..., None, None] * eye
            cov = _inv2(info)
            total += _logdet2(cov)[:, live].sum(axis=1)
        return total / (t1 - 1)


class InfoGainPolicy:
    """Greedy team information seeking over motion primitives (see the module docstring).

    Args:
        horizon: planning horizon (s).
        plan_dt: time step of the planner's predictions (s).
        n_headings: driving primitives (world headings evenly spaced); plus standing still.
        replan_every: env steps between replans.
        passes: coordinate-descent sweeps over the robots per replan.
        q_per_m: position variance (m^2) dead reckoning adds per metre driven.
        fusion_rate: fraction of the gap to ``P_j + R`` one relative update closes.
        tie_cost: cost per metre from a candidate's end to the nearest informative teammate.
        mcl: the planner of the robots that run MCL (a default
            :class:`~policies.scripted.infogain_mcl.MCLInfoGainPlanner` when ``None``).
    """

    name = "infogain"

    def __init__(
        self,
        horizon: float = 15.0,
        plan_dt: float = 1.0,
        n_headings: int = 8,
        replan_every: int = 10,
        passes: int = 2,
        q_per_m: float = 0.003,
        fusion_rate: float = 0.5,
        tie_cost: float = 1e-3,
        mcl: MCLInfoGainPlanner | None = None,
    ) -> None:
        for key, value in (("horizon", horizon), ("plan_dt", plan_dt), ("q_per_m", q_per_m),
                           ("fusion_rate", fusion_rate)):
            if not value > 0:
                raise ValueError(f"{key} must be > 0, got {value!r}")
        for key, value in (("n_headings", n_headings), ("replan_every", replan_every),
                           ("passes", passes)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{key} must be a positive integer, got {value!r}")
        if not tie_cost >= 0:
            raise ValueError(f"tie_cost must be >= 0, got {tie_cost!r}")
        self.horizon, self.plan_dt = float(horizon), float(plan_dt)
        self.n_headings, self.replan_every, self.passes = n_headings, replan_every, passes
        if not fusion_rate < 1:
            raise ValueError(f"fusion_rate must be < 1, got {fusion_rate!r}")
        self.q_per_m, self.fusion_rate, self.tie_cost = q_per_m, fusion_rate, tie_cost
        self.headings = 2 * np.pi * np.arange(n_headings) / n_headings
        if mcl is not None and not isinstance(mcl, MCLInfoGainPlanner):
            raise ValueError(f"mcl must be an MCLInfoGainPlanner, got {type(mcl).__name__}")
        self.mcl = mcl if mcl is not None else MCLInfoGainPlanner()
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` for a new episode."""
        self.env = env
        self._views = ViewBuilder(env)
        self._model = TeamInfoModel(env, self.plan_dt, self.q_per_m, self.fusion_rate)
        self._gps = self._model.gps
        self._steps = int(round(self.horizon / self.plan_dt))
        self.choice = np.full(env.config.n_robots, STOP)
        self._count = 0
        self._steer = Steering(env.config.n_robots)
        self._mcl_robots = _mcl_robots(env)
        if self._mcl_robots:
            self.mcl.reset(env, self._mcl_robots)

    # ------------------------------------------------------------------ planning
    def _paths(self, i: int, est: np.ndarray, options: np.ndarray) -> np.ndarray:
        """``(len(options), T + 1, 2)`` positions of robot ``i`` under each primitive."""
        cfg = self.env.config
        spec = cfg.robot_spec(i)
        t = self.plan_dt * np.arange(self._steps + 1)
        heading = np.where(options == STOP, 0.0, self.headings[np.maximum(options, 0)])
        turn = np.abs(wrap_angle(heading - est[i, 2])) / spec.max_turn_rate
        dist = spec.max_speed * np.maximum(0.0, t[None] - turn[:, None])
        dist[options == STOP] = 0.0
        xy = est[i, :2] + dist[..., None] * np.stack([np.cos(heading), np.sin(heading)], 1)[:, None]
        w, h = cfg.world_size
        margin = 2 * cfg.robot_radius
        return np.stack([np.clip(xy[..., 0], margin, w - margin),
                         np.clip(xy[..., 1], margin, h - margin)], -1)

    def plan(self) -> np.ndarray:
        """Choose every live robot's primitive; returns the choices (``-1`` = stand still)."""
        env = self.env
        n = env.config.n_robots
        est, cov = env.estimated_poses, env.estimated_covariances[:, :2, :2]
        live = np.zeros(n, dtype=bool)
        live[[env.agent_name_mapping[a] for a in env.agents]] = True
        options = np.append(np.arange(self.n_headings), STOP)
        current = np.stack([self._paths(i, est, self.choice[i : i + 1])[0] for i in range(n)])
        for _ in range(self.passes):
            for i in np.flatnonzero(live):
                cand = self._paths(i, est, options)
                paths = np.repeat(current[None], len(options), axis=0)
                paths[:, i] = cand
                cost = self._model.cost(paths, cov, live)
                cost += self.tie_cost * self._tie_distance(i, cand[:, -1], current, live)
                k = int(np.argmin(cost))
                self.choice[i] = options[k]
                current[i] = cand[k]
        return self.choice.copy()

    def _tie_distance(self, i: int, ends: np.ndarray, current: np.ndarray, live: np.ndarray):
        others = np.flatnonzero(live & (np.arange(len(live)) != i))
        useful = others[self._gps[others] != self._gps[i]]
        pool = useful if len(useful) else others
        if not len(pool):
            return np.zeros(len(ends))
        d = ends[:, None] - current[pool, -1][None]
        return np.hypot(d[..., 0], d[..., 1]).min(axis=1)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent: replan when due, then track the chosen primitive."""
        mcl = self.mcl.act(self.env.agents) if self._mcl_robots else {}
        if len(self._mcl_robots) == self.env.config.n_robots:
            return mcl
        if self._count % self.replan_every == 0:
            self.plan()
        self._count += 1
        actions = {}
        for agent in self.env.agents:
            if agent in mcl:
                actions[agent] = mcl[agent]
                continue
            view = self._views.view(agent, obs[agent])
            k = self.choice[view.index]
            if k == STOP:
                actions[agent] = np.zeros(2, dtype=np.float32)
            else:
                actions[agent] = self._steer.heading(view, float(self.headings[k]))
        return actions


def _mcl_robots(env) -> dict[int, tuple[int, int]]:
    """The robots whose beliefs are particle sets (the team beliefs' ``samples``):
    ``{robot: (backend index, local index)}``."""
    particle = env.beliefs.samples
    out = {}
    for b, backend in enumerate(env.backends):
        for local, g in enumerate(backend.robots.tolist()):
            if g in particle:
                out[g] = (b, local)
    return out
