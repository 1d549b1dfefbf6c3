"""The experiments of Howard, Mataric and Sukhatme as a library: behaviours and runners.

* :class:`DispersalPolicy` spreads a crowded team through a building using only
  each robot's own sensors: it steers towards long free laser beams pointing
  away from the teammates its robot detector sees.
* :class:`CircuitPolicy` keeps six robots still and drives the seventh around
  the ``circuit`` loop, back past the first robot. The driver is steered along
  the loop by its true pose (a stand-in for the paper's human driver); the
  estimator never sees it.
* :func:`run_dispersal` and :func:`run_circuit` run the scenarios with the
  centralized MLE and record the team's Eq. 15 relative errors over time;
  :func:`plot_howard` draws both curves.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import coop_loc_env
from coop_loc_env.scenarios.howard import CIRCUIT_LOOP, DRIVER
from estimators.geometry import wrap_angle
from estimators.relative_metrics import relative_errors

Progress = Callable[[int], None]


class DispersalPolicy:
    """Howard-style dispersal from each robot's own laser scan and robot detections.

    A potential field in the robot's frame: a constant pull forward, a push
    away from every laser return closer than ``influence_m`` (walls and
    teammates alike) and a push away from the teammates the robot detector
    sees (remembered for ``memory_s`` seconds, since the detector may run
    slower than the env). The robot turns towards the resulting vector and
    drives at a speed that falls with the clearance ahead.

    Args:
        away_weight: weight of the push away from detected teammates.
        obstacle_weight: weight of the push away from close laser returns.
        influence_m: laser returns closer than this push.
        clearance_m: obstacle distance ahead over which the robot slows down.
        memory_s: how long a detected teammate keeps repelling.
        open_weight: pull towards the most open direction (the longest beam, a little
            biased forward), which leads robots through doorways.
    """

    name = "dispersal"

    def __init__(
        self,
        away_weight: float = 1.0,
        obstacle_weight: float = 0.4,
        influence_m: float = 1.5,
        clearance_m: float = 0.8,
        memory_s: float = 1.0,
        open_weight: float = 1.5,
    ) -> None:
        self.open_weight = open_weight
        self.away_weight = away_weight
        self.obstacle_weight = obstacle_weight
        self.influence_m = influence_m
        self.clearance_m = clearance_m
        self.memory_s = memory_s
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset)."""
        self.env = env
        n = env.config.n_robots
        self._away = np.zeros((n, 2))  # push away from teammates, in each robot's frame
        self._age = np.full(n, np.inf)
        self._angles = env.sensors.beam_angles
        self._max_range = env.sensors.range_max

    def _update_repulsion(self) -> None:
        env = self.env
        readings = env.last_readings
        self._age += env.config.dt
        if readings is None:
            return
        det = readings.detections
        if not len(det):
            return
        obs, r, b = det.observer, det.z[:, 0], det.z[:, 1]
        push = -np.stack([np.cos(b), np.sin(b)], 1) / np.maximum(r, 0.5)[:, None]
        fresh = np.zeros((env.config.n_robots, 2))
        np.add.at(fresh, obs, push)
        seen = np.unique(obs)
        self._away[seen] = fresh[seen]
        self._age[seen] = 0.0

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """One action per live agent."""
        env = self.env
        self._update_repulsion()
        readings = env.last_readings
        out = {}
        for agent in env.agents:
            i = env.agent_name_mapping[agent]
            angles = self._angles[i]
            if readings is None or not readings.range_mask[i]:
                out[agent] = np.array([0.5, 0.0], dtype=np.float32)
                continue
            ranges = np.nan_to_num(readings.ranges[i, : len(angles)], nan=self._max_range[i])
            close = np.clip((self.influence_m - ranges) / np.maximum(ranges, 0.1), 0.0, None)
            units = np.stack([np.cos(angles), np.sin(angles)], 1)
            force = np.array([1.0, 0.0]) - self.obstacle_weight * close @ units
            free = np.minimum(ranges, self._max_range[i])
            force += self.open_weight * units[int(np.argmax(free + 0.5 * np.cos(angles)))]
            if self._age[i] <= self.memory_s:
                force += self.away_weight * self._away[i]
            target = float(np.arctan2(force[1], force[0]))
            ahead = np.abs(wrap_angle(angles)) <= np.pi / 4
            front = ranges[ahead].min() if ahead.any() else self._max_range[i]
            speed = np.clip((front - 0.4) / self.clearance_m, 0.0, 1.0) * max(np.cos(target), 0.0)
            turn = np.clip(2.0 * target, -1.0, 1.0)
            out[agent] = np.array([speed, turn], dtype=np.float32)
        return out


class CircuitPolicy:
    """Robots other than ``driver`` stand still; the driver follows ``waypoints``.

    The driver heads for each waypoint in turn (true pose: a stand-in for a
    human driver), slowing down in the turns, and stops after the last one.
    """

    name = "circuit"

    def __init__(
        self, waypoints: np.ndarray | None = None, driver: int = DRIVER, reach_m: float = 0.4
    ) -> None:
        self.waypoints = np.asarray(circuit_waypoints() if waypoints is None else waypoints,
                                    dtype=float)
        if self.waypoints.ndim != 2 or self.waypoints.shape[1] != 2:
            raise ValueError(f"waypoints must be (k, 2), got shape {self.waypoints.shape}")
        self.driver = int(driver)
        self.reach_m = float(reach_m)
        self.env = None

    def reset(self, env, seed: int | None = None) -> None:
        """Bind to ``env`` (already reset) and start at the first waypoint."""
        if not 0 <= self.driver < env.config.n_robots:
            raise ValueError(f"driver must be a robot index < {env.config.n_robots}, "
                             f"got {self.driver!r}")
        self.env = env
        self.next = 0

    @property
    def finished(self) -> bool:
        """Whether the driver has passed its last waypoint."""
        return self.next >= len(self.waypoints)

    def act(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Zero for the stationary robots; pure pursuit of the waypoints for the driver."""
        env = self.env
        out = {a: np.zeros(2, dtype=np.float32) for a in env.agents}
        pose = env.world.poses[self.driver]
        while not self.finished and (
            np.hypot(*(self.waypoints[self.next] - pose[:2])) < self.reach_m
        ):
            self.next += 1
        agent = env.possible_agents[self.driver]
        if self.finished or agent not in out:
            return out
        dx, dy = self.waypoints[self.next] - pose[:2]
        err = wrap_angle(np.arctan2(dy, dx) - pose[2])
        speed = np.clip(np.cos(err), 0.0, 1.0) ** 4
        out[agent] = np.array([speed, np.clip(2.0 * err, -1.0, 1.0)], dtype=np.float32)
        return out


def circuit_waypoints(overshoot_m: float = 5.5) -> np.ndarray:
    """The loop's corners counter-clockwise, back to the start corner, then ``overshoot_m``
    along the first leg again (past robot 0, to re-sight it)."""
    loop = np.asarray(CIRCUIT_LOOP, dtype=float)
    first = loop[1] - loop[0]
    end = loop[0] + overshoot_m * first / np.linalg.norm(first)
    return np.vstack([loop[1:], loop[:1], end[None]])


def _run(env, policy, n_steps: int, seed: int, progress: Progress | None) -> dict[str, Any]:
    """Run ``n_steps`` steps; records the team's Eq. 15 errors and the detections."""
    obs, _ = env.reset(seed=seed)
    policy.reset(env, seed)
    errors, spread, pairs = [], [], []
    for _ in range(n_steps):
        if not env.agents:
            break
        obs, *_ = env.step(policy.act(obs))
        errors.append(relative_errors(env.estimated_poses, env.world.poses))
        xy = env.world.poses[:, :2]
        d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        np.fill_diagonal(d, np.inf)
        spread.append(float(d[np.isfinite(d)].mean()))
        det = env.last_readings.detections
        pairs.append(set(zip(det.observer.tolist(), det.target.tolist(), strict=True)))
        if progress is not None:
            progress(1)
    errors = np.array(errors)
    t = (np.arange(len(errors)) + 1) * env.config.dt
    return {"times_s": t, "errors": errors, "mean_distance_m": np.array(spread), "pairs": pairs}


def run_dispersal(
    seed: int = 0, duration_s: float = 120.0, progress: Progress | None = None, **overrides: Any
) -> dict[str, Any]:
    """Run ``dispersal`` with :class:`DispersalPolicy` and the centralized MLE.

    Returns ``times_s`` ``(T,)``, ``range_error_m``, ``bearing_error_rad``,
    ``orientation_error_rad`` (team means over ordered pairs, Eq. 15) and
    ``mean_distance_m`` (true distance between robots, mean over pairs:
    how far the team has spread), plus ``detections`` per step.
    """
    overrides.setdefault("estimator", "mle")
    n_steps = _steps(duration_s, coop_loc_env.make_config("dispersal", **overrides))  # fail early
    env = coop_loc_env.parallel_env("dispersal", **overrides)
    rec = _run(env, DispersalPolicy(), n_steps, seed, progress)
    env.close()
    e = rec["errors"]
    return {
        "times_s": rec["times_s"],
        "range_error_m": e[:, 0],
        "bearing_error_rad": e[:, 1],
        "orientation_error_rad": e[:, 2],
        "mean_distance_m": rec["mean_distance_m"],
        "detections": np.array([len(p) for p in rec["pairs"]]),
    }


def run_circuit(
    seed: int = 0, duration_s: float = 175.0, progress: Progress | None = None,
    after_s: float = 2.0, **overrides: Any
) -> dict[str, Any]:
    """Run ``circuit`` with :class:`CircuitPolicy` and the centralized MLE.

    Returns the series of :func:`run_dispersal` (without ``detections``), the
    times the driver and a stationary robot first saw each other
    (``sightings_s``: robot -> time), ``closure_time_s`` (the first sighting of
    robot 0 after the driver has been out of its sight for more than 30 s; NaN
    if the loop was not closed), ``error_before_closure_m`` (team range error at
    the last step before it) and ``error_after_closure_m`` (``after_s`` seconds
    after it, once the closing observation is optimized in).
    """
    overrides.setdefault("estimator", "mle")
    n_steps = _steps(duration_s, coop_loc_env.make_config("circuit", **overrides))  # fail early
    env = coop_loc_env.parallel_env("circuit", **overrides)
    rec = _run(env, CircuitPolicy(), n_steps, seed, progress)
    env.close()
    t, e = rec["times_s"], rec["errors"]
    seen_steps: dict[int, list[int]] = {}
    for k, pairs in enumerate(rec["pairs"]):
        for a, b in pairs:
            if DRIVER in (a, b):
                seen_steps.setdefault(b if a == DRIVER else a, []).append(k)
    sightings = {int(r): float(t[ks[0]]) for r, ks in sorted(seen_steps.items())}
    closure = float("nan")
    steps0 = np.asarray(seen_steps.get(0, []))
    gaps = np.flatnonzero(np.diff(steps0) * env.config.dt > 30.0)
    before = after = float("nan")
    if len(gaps):
        k = int(steps0[gaps[0] + 1])
        closure = float(t[k])
        before = float(e[k - 1, 0])
        k_after = min(k + int(round(after_s / env.config.dt)), len(t) - 1)
        after = float(e[k_after, 0])
    return {
        "times_s": t,
        "range_error_m": e[:, 0],
        "bearing_error_rad": e[:, 1],
        "orientation_error_rad": e[:, 2],
        "sightings_s": sightings,
        "closure_time_s": closure,
        "error_before_closure_m": before,
        "error_after_closure_m": after,
    }


def _steps(duration_s: float, cfg) -> int:
    n_steps = int(round(duration_s / cfg.dt))
    if not 1 <= n_steps <= cfg.max_cycles:
        hint = f" (raise it: --set max_cycles={n_steps})" if n_steps > cfg.max_cycles else ""
        raise ValueError(
            f"duration_s={duration_s!r} needs {n_steps} steps; allowed 1..max_cycles="
            f"{cfg.max_cycles}{hint}"
        )
    return n_steps


def plot_howard(dispersal: dict[str, Any] | None, circuit: dict[str, Any] | None,
                path: str | Path) -> Path:
    """Range error vs time for both experiments (cf. Howard et al.'s figures)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    panels = [(k, r) for k, r in (("dispersal", dispersal), ("circuit", circuit)) if r]
    fig = Figure(figsize=(7.0 * max(len(panels), 1), 4.2), dpi=100)
    FigureCanvasAgg(fig)
    for j, (name, res) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), j + 1)
        ax.plot(res["times_s"], res["range_error_m"], color="tab:blue", lw=1.4,
                label="mean relative range error")
        if name == "dispersal":
            ax2 = ax.twinx()
            ax2.plot(res["times_s"], res["mean_distance_m"], color="tab:gray", lw=1.0,
                     ls="--", label="mean distance between robots")
            ax2.set_ylabel("mean distance between robots (m)", color="tab:gray")
            ax.set_title("dispersal: 20 robots spread out of one room", fontsize=10)
            handles = ax.get_legend_handles_labels()[0] + ax2.get_legend_handles_labels()[0]
            ax.legend(handles=handles, loc="upper left", fontsize=8)
        else:
            for k, (robot, ts) in enumerate(res["sightings_s"].items()):
                ax.axvline(ts, color="tab:green", lw=0.8, ls=":",
                           label="first sighting of robot (number)" if k == 0 else None)
                ax.annotate(str(robot), (ts, 0.0), xycoords=("data", "axes fraction"),
                            xytext=(2, 3), textcoords="offset points", fontsize=8,
                            color="tab:green")
            if np.isfinite(res["closure_time_s"]):
                ax.axvline(res["closure_time_s"], color="tab:red", lw=1.2, ls="--",
                           label="loop closure (robot 0 seen again)")
            ax.set_title("circuit: one robot drives past six stationary ones", fontsize=10)
            ax.legend(loc="upper right", fontsize=8)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("mean relative range error (m)")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path
