"""Run policies on scenarios (used by ``scripts/evaluate.py`` and ``scripts/render_episode.py``).

* :func:`run_episodes` runs a policy (an object or a spec for
  :func:`policies.learning.loader.make_policy`) for N seeded episodes and returns
  one record per episode (the figures of :mod:`policies.episode` plus time
  series and the final maps for plots); :mod:`policies.experiments.report`
  reduces them;
* :func:`record_frames` runs one episode with rendering, for a GIF;
* :func:`parse_overrides` reads the ``--set KEY=VALUE`` options of the scripts
  (:func:`coop_loc_env.cli.parse_overrides`, kept here for the scripts that import it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

import coop_loc_env
from coop_loc_env.cli import parse_overrides  # noqa: F401  (re-exported)
from policies.episode import env_overrides_for, run_episode
from policies.learning.loader import make_policy
from policies.scripted.baselines import Policy


def run_episodes(
    scenario: str,
    policy: Policy | str,
    n_episodes: int,
    seed: int = 0,
    overrides: dict[str, Any] | None = None,
    progress: bool = True,
) -> list[dict[str, Any]]:
    """Run ``policy`` on ``scenario`` for ``n_episodes`` (episode ``k`` seeded ``seed + k``).

    Args:
        scenario: registered scenario name.
        policy: a policy object or a spec for :func:`make_policy`.
        n_episodes: number of episodes (>= 1).
        seed: seed of the first episode.
        overrides: config overrides for the scenario (e.g. ``{"max_cycles": 200}``).
        progress: show a tqdm bar over all steps.

    Returns:
        One record per episode: the :data:`policies.episode.FIGURES`, ``seed``, ``steps``,
        ``team_return``, ``state_steps`` (robot-steps per FSM state, when the
        policy reports states), ``series`` (per-step arrays) and ``maps``
        (final estimated and true height grids, indexed ``[x, y]``).
    """
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be a positive integer, got {n_episodes!r}")
    if isinstance(policy, str):
        policy = make_policy(policy)
    env = coop_loc_env.parallel_env(scenario, **env_overrides_for(policy, overrides))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_episodes * env.config.max_cycles, unit="step", desc=scenario)
    episodes = []
    try:
        for k in range(n_episodes):
            ep = run_episode(env, policy, seed + k, (lambda e, i: bar.update()) if bar else None)
            episodes.append(ep)
            if bar is not None:
                bar.update(env.config.max_cycles - ep["steps"])  # early termination
                err, cov = ep["localization_error_m"], ep["coverage"]
                bar.set_postfix(err=f"{err:.2f}", cov=f"{cov:.3f}")
    finally:
        if bar is not None:
            bar.close()
        env.close()
    return episodes


def record_frames(
    scenario: str,
    policy: Policy | str,
    seed: int = 0,
    overrides: dict[str, Any] | None = None,
    every: int = 5,
    progress: bool = True,
) -> tuple[list[np.ndarray], dict[str, Any]]:
    """Run one episode with ``rgb_array`` rendering; returns frames and the episode record.

    A frame is taken after reset and then every ``every`` steps (and at the end).
    """
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every must be a positive integer, got {every!r}")
    if isinstance(policy, str):
        policy = make_policy(policy)
    env = coop_loc_env.parallel_env(scenario, render_mode="rgb_array",
                                    **env_overrides_for(policy, overrides))
    frames: list[np.ndarray] = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=env.config.max_cycles, unit="step", desc=f"{scenario} (render)")

    steps = [0]

    def on_step(e, infos):
        steps[0] += 1
        if bar is not None:
            bar.update()
        if steps[0] % every == 0 or not e.agents:
            frames.append(e.render())

    try:
        ep = run_episode(env, policy, seed, on_step, on_reset=lambda e: frames.append(e.render()))
    finally:
        if bar is not None:
            bar.close()
        env.close()
    return frames, ep
