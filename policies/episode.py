"""One episode of any policy on an env, and the figures recorded for it.

:func:`run_episode` is the episode loop every runner shares (evaluation,
comparison, training's periodic evaluation). Figures per episode
(:data:`FIGURES`): ``localization_error_m`` (team localization error: mean over
robots and steps of the true position error of each live robot's belief),
``coverage`` (fraction of the drivable area in the team map at the end),
``map_rmse_m`` (team map vs true height field at the end), ``collisions`` (new
contacts summed over robots and steps; a contact between two robots counts for
both), ``tip_overs`` (robots that tipped over).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from policies.scripted.baselines import Policy

FIGURES = ("localization_error_m", "coverage", "map_rmse_m", "collisions", "tip_overs")


def env_overrides_for(policy: Policy, overrides: dict[str, Any] | None) -> dict[str, Any]:
    """The config overrides of an env for ``policy``: the observation settings a trained
    policy carries (``policy.env_settings``, e.g. ``obs_format="dict"`` and the belief
    map's grid), then ``overrides`` (which win; a clash with the network's inputs is
    then reported by the policy's shape check)."""
    return {**dict(getattr(policy, "env_settings", None) or {}), **(overrides or {})}


def run_episode(
    env, policy: Policy, seed: int, on_step=None, on_reset=None
) -> dict[str, Any]:
    """Run one episode of ``policy`` on ``env``; returns its figures and series.

    ``on_reset(env)`` is called after the reset and ``on_step(env, infos)``
    after every step (e.g. a progress bar, a renderer).
    """
    obs, infos = env.reset(seed=seed)
    policy.reset(env, seed=seed)
    if on_reset is not None:
        on_reset(env)
    n = env.config.n_robots
    errors: list[np.ndarray] = []
    stds: list[np.ndarray] = []
    collisions = 0
    team_return = 0.0
    states: dict[str, int] = {}
    tipped: set[str] = set()
    while env.agents:
        obs, rewards, _term, _trunc, infos = env.step(policy.act(obs))
        err = np.full(n, np.nan)
        std = np.full(n, np.nan)
        for agent, info in infos.items():
            i = env.agent_name_mapping[agent]
            err[i] = info["position_error"]
            cov = info["pose_cov"]
            std[i] = np.sqrt(0.5 * (cov[0, 0] + cov[1, 1]))
            collisions += int(info["collisions"])
            if info["tipped_over"]:
                tipped.add(agent)
        errors.append(err)
        stds.append(std)
        team_return += float(sum(rewards.values()))
        if hasattr(policy, "states"):
            for s in policy.states().values():
                states[s] = states.get(s, 0) + 1
        if on_step is not None:
            on_step(env, infos)
    last = next(iter(infos.values()))
    err_arr = np.array(errors)
    return {
        "seed": int(seed),
        "steps": len(errors),
        "localization_error_m": float(np.nanmean(err_arr)),
        "coverage": float(last["coverage"]),
        "map_rmse_m": float(last["map_rmse"]),
        "collisions": int(collisions),
        "tip_overs": len(tipped),
        "team_return": team_return,
        "state_steps": states,
        "series": {
            "time_s": (np.arange(len(errors)) + 1) * env.config.dt,
            "position_error_m": err_arr,
            "position_std_m": np.array(stds),
        },
        "maps": {
            "estimated": env.terrain_map.elevation,
            "true": env.mapper.true_height,
            "objects": np.array(env.terrain_map.objects, dtype=float).reshape(-1, 3),
            "extent": (0.0, env.config.world_size[0], 0.0, env.config.world_size[1]),
            "layout": _layout_marks(env.world),
        },
    }


def _layout_marks(world) -> dict[str, Any]:
    """The known map's marks for the terrain plot: canopies ``(k, 3)`` (x, y, radius),
    round obstacles by kind ``(k, 3)``, and the steep cells' grid with its axes."""
    layout, terrain = world.layout, world.terrain
    canopy = np.c_[layout.canopy_centers, layout.canopy_radii].reshape(-1, 3)
    round_obstacles: dict[str, list] = {}
    for o in layout.obstacles:
        if o.shape == "circle":
            round_obstacles.setdefault(o.kind, []).append((*o.center, o.radius))
    return {"canopy": canopy,
            "obstacles": {k: np.array(v, dtype=float) for k, v in round_obstacles.items()},
            "steep": (terrain.xs, terrain.ys, terrain.steep.copy())}


def episode_figures(ep: dict[str, Any]) -> dict[str, Any]:
    """The JSON-serializable part of an episode record (no series or maps)."""
    return {k: v for k, v in ep.items() if k not in ("series", "maps")}
