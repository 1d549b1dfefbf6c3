"""Matplotlib renderer: terrain shading, canopy, obstacles, true and estimated poses.

Each robot has a colour: its true pose is a filled disc with a heading tick,
its estimate a cross, its belief a 2-sigma ellipse (EKF, MLE) or a subsample
of its particles (MCL, as in Fox et al.'s sample-set figures: a multi-modal
belief shows as several clouds). Range beams, detections and a key are drawn
too; the title names the scenario, the estimator and the time.

Imported lazily by :meth:`CoopLocParallelEnv.render`, so matplotlib is only
needed when rendering (``pip install -e ".[render]"`` from the repository).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from coop_loc_env.records import Beliefs, Readings


class RenderSource(Protocol):
    """What the renderer reads of an env: its public state only."""

    config: Any
    world: Any
    sensors: Any
    metadata: dict

    @property
    def beliefs(self) -> Beliefs: ...

    @property
    def last_readings(self) -> Readings | None: ...

    @property
    def step_count(self) -> int: ...

ROBOT_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown",
                "tab:pink", "tab:olive", "tab:cyan", "tab:gray")
OBSTACLE_COLORS = {"tree": "#2e6b30", "rock": "#6d6d6d", "wall": "#333333",
                   "building": "#555555", "ooi": "#d4a017"}
#: What each obstacle kind is, in the frames' legend.
OBSTACLE_LABELS = {"tree": "tree trunk", "rock": "rock", "wall": "wall", "building": "building",
                   "ooi": "object of interest (mapped)"}
CANOPY_COLOR = "#1b4d1b"
STEEP_COLOR = "#b22222"
#: Robots listed one by one in the legend up to this team size (beyond, the GPS ones only).
LEGEND_ROBOTS = 8


def _import_matplotlib():
    try:
        from matplotlib import patches
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.collections import LineCollection
        from matplotlib.figure import Figure
    except ImportError as err:  # pragma: no cover - exercised only without matplotlib
        raise ModuleNotFoundError(
            "rendering needs matplotlib: pip install -e '.[render]' in the repository (or "
            "pip install matplotlib imageio)", name="matplotlib"
        ) from err
    from matplotlib.lines import Line2D

    return Figure, FigureCanvasAgg, patches, LineCollection, Line2D


def _has_display() -> bool:
    import os

    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


PARTICLES_DRAWN = 250  # per robot: enough to show every mode, few enough to see the map


def particle_subsample(
    particles: np.ndarray, weights: np.ndarray, k: int = PARTICLES_DRAWN, seed: int = 0
) -> np.ndarray:
    """``(min(k, N), 2)`` particle positions drawn in proportion to ``weights`` (systematic
    resampling with its own generator: drawing never touches the env's random streams)."""
    n = len(particles)
    if n <= k:
        return particles[:, :2]
    cum = np.cumsum(weights)
    start = np.random.default_rng(seed).uniform(0.0, cum[-1] / k)
    idx = np.searchsorted(cum, start + cum[-1] / k * np.arange(k))
    return particles[np.minimum(idx, n - 1), :2]


def particle_sets(env: RenderSource) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Robot index -> ``(N, 3)`` particles and ``(N,)`` weights of every particle-filter
    belief (the team beliefs' particle sets)."""
    return {int(robot): (ps.states, ps.weights) for robot, ps in env.beliefs.samples.items()}


def covariance_ellipse(mean: np.ndarray, cov: np.ndarray, n_sigma: float = 2.0, points: int = 36):
    """Points ``(points, 2)`` on the ``n_sigma`` ellipse of a 2x2 covariance."""
    vals, vecs = np.linalg.eigh(cov)
    vals = np.maximum(vals, 0.0)
    t = np.linspace(0, 2 * np.pi, points)
    circle = np.stack([np.cos(t), np.sin(t)], 1)
    return mean + n_sigma * (circle * np.sqrt(vals)) @ vecs.T


class Renderer:
    """Draws an env's current state into an RGB array (and a window for ``human``)."""

    def __init__(self, env: RenderSource, size_px: int = 600) -> None:
        self.env = env
        figure_cls, canvas_cls, self.patches, self.line_collection, line = _import_matplotlib()
        dpi = 100
        self.fig = figure_cls(figsize=(size_px / dpi, size_px / dpi), dpi=dpi)
        self.canvas = canvas_cls(self.fig)
        self.ax = self.fig.add_axes((0.01, 0.17, 0.98, 0.78))
        self.title = self.fig.text(0.5, 0.985, "", ha="center", va="top", fontsize=9)
        self._window = None
        self._frame = 0
        estimators = env.config.estimators
        self.estimator_label = "+".join(dict.fromkeys(estimators))
        grey = "0.35"
        key = [
            line([], [], marker="o", ls="", color=grey, ms=7, label="true pose"),
            line([], [], marker="x", ls="", color=grey, ms=7, mew=2, label="estimate"),
        ]
        if any(e != "mcl" for e in estimators):
            key.append(line([], [], color=grey, lw=1, label="2-sigma belief"))
        if "mcl" in estimators:
            key.append(line([], [], marker=".", ls="", color=grey, ms=4, label="particles"))
        key += [
            line([], [], color="k", lw=0.8, ls="--", label="detection"),
            line([], [], color="m", lw=0.8, ls="--", label="false detection"),
            line([], [], color="red", lw=0.8, alpha=0.6, label="range beams"),
        ]
        self._line = line
        self._key = key + self._robot_key()
        self._legend = None
        self._layout_kinds: tuple | None = None

    def _robot_key(self) -> list:
        """Legend entries for the robots' colours and which robots have GPS."""
        cfg = self.env.config
        gps = [cfg.robot_spec(i).has_gps for i in range(cfg.n_robots)]
        mixed = len(set(cfg.estimators)) > 1
        if cfg.n_robots <= LEGEND_ROBOTS:
            return [self._robot_entry(i, f"robot_{i}: {'GPS' if gps[i] else 'no GPS'}"
                                         + (f", {cfg.estimators[i]}" if mixed else ""))
                    for i in range(cfg.n_robots)]
        with_gps = [i for i in range(cfg.n_robots) if gps[i]]
        if not with_gps:
            return [self._robot_entry(0, f"robots ({cfg.n_robots}): none has GPS")]
        shown = ", ".join(map(str, with_gps[:6])) + (", ..." if len(with_gps) > 6 else "")
        return [self._robot_entry(with_gps[0], f"GPS: robots {shown} ({len(with_gps)} of "
                                               f"{cfg.n_robots})")]

    def _robot_entry(self, i: int, label: str):
        return self.patches.Patch(color=ROBOT_COLORS[i % len(ROBOT_COLORS)], label=label)

    def _layout_key(self) -> list:
        """Legend entries for what the map shows: canopy, steep ground, obstacle kinds."""
        world = self.env.world
        key = []
        if len(world.layout.canopy_radii):
            key.append(self.patches.Patch(color=CANOPY_COLOR, alpha=0.25,
                                          label="tree canopy (weak GPS)"))
        if world.terrain.steep.any():
            key.append(self.patches.Patch(color=STEEP_COLOR, alpha=0.35,
                                          label="steep ground (tips over)"))
        for kind in dict.fromkeys(o.kind for o in world.layout.obstacles):
            key.append(self.patches.Patch(color=OBSTACLE_COLORS.get(kind, "k"),
                                          label=OBSTACLE_LABELS.get(kind, kind)))
        return key

    def _update_legend(self) -> None:
        """(Re)draw the legend when the layout's kinds of marks change (a new episode)."""
        world = self.env.world
        kinds = (len(world.layout.canopy_radii) > 0, bool(world.terrain.steep.any()),
                 tuple(dict.fromkeys(o.kind for o in world.layout.obstacles)))
        if kinds == self._layout_kinds:
            return
        self._layout_kinds = kinds
        if self._legend is not None:
            self._legend.remove()
        self._legend = self.fig.legend(
            handles=self._key + self._layout_key(), loc="lower center", ncol=4, fontsize=7,
            frameon=False, handlelength=1.6, columnspacing=1.0, borderaxespad=0.2)

    def draw(self) -> np.ndarray:
        """Render the current state; returns ``uint8 (H, W, 3)``."""
        env = self.env
        cfg = env.config
        world = env.world
        ax = self.ax
        ax.clear()
        self._update_legend()
        w, h = cfg.world_size
        terrain = world.terrain
        if np.ptp(terrain.z) > 0:
            ax.imshow(terrain.z, origin="lower", extent=(0, w, 0, h), cmap="terrain", alpha=0.8)
        else:  # flat floor (indoor scenarios): a plain background shows the particles best
            ax.add_patch(self.patches.Rectangle((0, 0), w, h, color="#f2f2ee", lw=0))
        if terrain.steep.any():
            ax.contourf(terrain.xs, terrain.ys, terrain.steep.astype(float), levels=[0.5, 1.5],
                        colors=[STEEP_COLOR], alpha=0.35)
        for c, r in zip(world.layout.canopy_centers, world.layout.canopy_radii, strict=True):
            ax.add_patch(self.patches.Circle(c, r, color=CANOPY_COLOR, alpha=0.25, lw=0))
        for o in world.layout.obstacles:
            color = OBSTACLE_COLORS.get(o.kind, "k")
            if o.shape == "circle":
                ax.add_patch(self.patches.Circle(o.center, o.radius, color=color))
            elif o.shape == "segment":
                ax.plot(*zip(o.a, o.b, strict=True), color=color, lw=2)
            else:
                ax.add_patch(self.patches.Polygon(o.vertices, color=color))
        readings = env.last_readings
        poses = world.poses
        beliefs = env.beliefs
        est, cov = beliefs.mean, beliefs.cov
        if readings is not None and readings.range_mask.any():
            segs = []
            for i in np.nonzero(readings.range_mask)[0]:
                angles = env.sensors.beam_angles[i] + poses[i, 2]
                rng = readings.ranges[i, : len(angles)]
                for a, r in zip(angles, rng, strict=True):
                    segs.append([poses[i, :2], poses[i, :2] + r * np.array([np.cos(a), np.sin(a)])])
            ax.add_collection(self.line_collection(segs, colors="red", linewidths=0.3, alpha=0.35))
        if readings is not None and len(readings.detections):
            det = readings.detections
            for o, t, genuine in zip(det.observer, det.target, det.genuine, strict=True):
                ax.plot(*zip(poses[o, :2], poses[t, :2], strict=True),
                        color="k" if genuine else "m", lw=0.8, ls="--")
        clouds = particle_sets(env)
        self._frame += 1
        for i in range(cfg.n_robots):
            color = ROBOT_COLORS[i % len(ROBOT_COLORS)]
            x, y, th = poses[i]
            if i in clouds:
                xy = particle_subsample(*clouds[i], seed=self._frame)
                ax.scatter(xy[:, 0], xy[:, 1], s=3, color=color, alpha=0.7, lw=0)
            else:
                ell = covariance_ellipse(est[i, :2], cov[i, :2, :2])
                ax.plot(ell[:, 0], ell[:, 1], color=color, lw=1)
            ax.add_patch(self.patches.Circle((x, y), cfg.robot_radius, color=color, alpha=0.9))
            ax.plot([x, x + 0.8 * np.cos(th)], [y, y + 0.8 * np.sin(th)], color="k", lw=1)
            ax.plot(est[i, 0], est[i, 1], marker="x", color=color, ms=7, mew=2)
        ax.set_xlim(0, w)
        ax.set_ylim(0, h)
        ax.set_aspect("equal")
        ax.set_axis_off()
        self.title.set_text(f"{cfg.name}, estimator {self.estimator_label}, "
                            f"t = {env.step_count * cfg.dt:.1f} s")
        self.canvas.draw()
        buf = np.asarray(self.canvas.buffer_rgba())
        return np.ascontiguousarray(buf[..., :3])

    def show(self, frame: np.ndarray) -> None:
        """Show ``frame`` in a window (``human`` mode); silently a no-op without a display."""
        if not _has_display():
            return
        import matplotlib.pyplot as plt

        if self._window is None:
            plt.ion()
            fig, ax = plt.subplots()
            ax.set_axis_off()
            self._window = (fig, ax.imshow(frame))
        else:
            self._window[1].set_data(frame)
        plt.pause(1.0 / self.env.metadata["render_fps"])

    def close(self) -> None:
        """Close the figures."""
        self.fig.clear()
        if self._window is not None:
            import matplotlib.pyplot as plt

            plt.close(self._window[0])
            self._window = None
