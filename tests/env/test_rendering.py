"""What a rendered frame shows: particles for MCL, ellipses otherwise, a key and a title."""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.rendering import ROBOT_COLORS, particle_subsample


def _rendered(scenario: str, **kw):
    env = coop_loc_env.parallel_env(scenario, render_mode="rgb_array", n_robots=2,
                                    max_cycles=5, **kw)
    env.reset(seed=0)
    env.step({a: np.zeros(2) for a in env.agents})
    frame = env.render()
    return env, env._renderer, frame


def _legend_labels(renderer) -> list[str]:
    return [t.get_text() for legend in renderer.fig.legends for t in legend.get_texts()]


def test_mcl_frame_draws_each_robots_particles_in_its_colour():
    from matplotlib.colors import to_rgba

    env, r, frame = _rendered("symmetric_hallway", n_particles=200)
    assert frame.shape == (600, 600, 3) and frame.dtype == np.uint8
    clouds = [c for c in r.ax.collections if c.get_offsets().shape[0] > 50]
    assert len(clouds) == 2
    for i, cloud in enumerate(clouds):
        assert np.allclose(cloud.get_facecolor()[0][:3], to_rgba(ROBOT_COLORS[i])[:3])
    labels = _legend_labels(r)
    assert "particles" in labels and "2-sigma belief" not in labels
    assert r.title.get_text().startswith("symmetric_hallway, estimator mcl")


def test_ekf_frame_draws_ellipses_and_says_which_estimator():
    env, r, _ = _rendered("symmetric_hallway", estimator="ekf")
    assert not [c for c in r.ax.collections if c.get_offsets().shape[0] > 50]
    labels = _legend_labels(r)
    for label in ("true pose", "estimate", "2-sigma belief", "detection", "range beams"):
        assert label in labels
    assert "particles" not in labels
    assert "estimator ekf" in r.title.get_text()


def test_particle_subsample_follows_the_weights():
    particles = np.zeros((1000, 3))
    particles[500:, 0] = 10.0
    weights = np.r_[np.full(500, 0.9 / 500), np.full(500, 0.1 / 500)]
    xy = particle_subsample(particles, weights, k=200)
    assert xy.shape == (200, 2)
    assert np.mean(xy[:, 0] == 0.0) == pytest.approx(0.9, abs=0.01)
    assert np.array_equal(particle_subsample(particles[:10], weights[:10], k=200),
                          particles[:10, :2])


def test_error_plot_names_the_faint_lines(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from policies.experiments import plots

    saved = {}
    real = Figure.savefig

    def keep(fig, *a, **k):
        saved["fig"] = fig
        return real(fig, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    eps = [{"seed": s, "series": {"time_s": np.arange(3.0),
                                  "position_error_m": np.ones((3, 2))}} for s in (4, 5, 6)]
    plots.plot_errors(eps, tmp_path / "e.png")
    labels = [t.get_text() for t in saved["fig"].axes[0].get_legend().get_texts()]
    assert labels == ["robot_0 (seed 4)", "robot_1 (seed 4)",
                      "other episodes (seeds 5, 6), same colours"]


def test_missing_matplotlib_names_an_install_that_works(monkeypatch):
    import sys

    from coop_loc_env import rendering

    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)  # import fails
    with pytest.raises(ImportError, match=r"pip install -e '\.\[render\]'"):
        rendering._import_matplotlib()


def test_frame_legend_names_the_map_marks_and_which_robots_have_gps():
    env, r, _ = _rendered("rendezvous")
    labels = _legend_labels(r)
    for label in ("tree canopy (weak GPS)", "tree trunk", "rock",
                  "object of interest (mapped)"):
        assert label in labels
    gps = [env.config.robot_spec(i).has_gps for i in range(env.config.n_robots)]
    assert gps == [True, False]  # rendezvous: every second robot without GPS
    assert "robot_0: GPS" in labels and "robot_1: no GPS" in labels


def test_terrain_plot_says_which_episode_and_names_every_mark(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    from policies.experiments import plots
    from policies.experiments.runner import run_episodes

    saved = {}
    real = Figure.savefig

    def keep(fig, *a, **k):
        saved["fig"] = fig
        return real(fig, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    ep = run_episodes("outdoor_terrain", "still", 1, seed=3, overrides={"max_cycles": 5},
                      progress=False)[0]
    plots.plot_terrain(ep, tmp_path / "t.png")
    fig = saved["fig"]
    assert fig._suptitle.get_text().startswith("episode seed 3: final coverage")
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    for label in ("unmapped (left panel)", "tree canopy (weak GPS)", "tree trunk", "rock",
                  "object of interest", "steep ground (tips over)"):
        assert label in labels
    assert fig.axes[-1].get_ylabel() == "elevation (m), both panels"  # the colorbar
    assert fig.axes[0].get_xlim() == (0.0, 40.0)  # marks at the border do not widen it


def test_large_teams_list_only_the_gps_robots():
    from coop_loc_env.rendering import LEGEND_ROBOTS, Renderer

    for n, each in ((LEGEND_ROBOTS, True), (LEGEND_ROBOTS + 1, False)):
        env = coop_loc_env.parallel_env("rendezvous", n_robots=n, max_cycles=5)
        env.reset(seed=0)
        labels = [p.get_label() for p in Renderer(env)._robot_key()]
        if each:
            assert labels == [f"robot_{i}: {'no GPS' if i % 2 else 'GPS'}" for i in range(n)]
        else:
            assert labels == ["GPS: robots 0, 2, 4, 6, 8 (5 of 9)"]
    assert LEGEND_ROBOTS == 8
