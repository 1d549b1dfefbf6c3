"""Run policies on scenarios and summarize what happened (used by ``scripts/evaluate.py``).

* :func:`make_policy` turns a registered policy name (:func:`policy_names`:
  ``fsm``, ``random``, ``seek``, ``still``, ``wander``; :func:`register_policy`
  adds one) or the path of a saved stable-baselines3 model (``.zip``) into a
  policy object;
* :func:`run_episodes` runs it for N seeded episodes and returns one record
  per episode (scalar figures plus time series and the final maps for plots);
* :func:`summarize` reduces the records to mean and standard deviation.

Figures per episode (:data:`FIGURES`): ``localization_error_m`` (team
localization error: mean over robots and steps of the true position error of
each live robot's belief), ``coverage`` (fraction of the drivable area in the
team map at the end), ``map_rmse_m`` (team map vs true height field at the
end), ``collisions`` (new contacts summed over robots and steps; a contact
between two robots counts for both), ``tip_overs`` (robots that tipped over).
"""

from __future__ import annotations

import ast
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import coop_loc_env
from policies.baselines import Policy, RandomPolicy, SeekTeammatePolicy, StandStillPolicy
from policies.fsm import FSMPolicy
from policies.learned import (  # noqa: F401 (re-exported)
    SB3Policy,
    detect_sb3_algo,
    load_learned_policy,
)

FIGURES = ("localization_error_m", "coverage", "map_rmse_m", "collisions", "tip_overs")

PolicyFactory = Callable[[str], Policy]
"""Builds a policy from the argument after ``NAME:`` in a spec (``""`` when there is none)."""
_POLICIES: dict[str, tuple[PolicyFactory, str]] = {}


def register_policy(name: str, factory: PolicyFactory, description: str) -> None:
    """Register ``factory`` as policy ``name`` for :func:`make_policy` (and ``evaluate.py``)."""
    if name in _POLICIES or ":" in name:
        raise ValueError(f"policy name {name!r} is taken or contains ':'")
    _POLICIES[name] = (factory, description)


def policy_names() -> list[str]:
    """The registered policy names, in registration order."""
    return list(_POLICIES)


def policy_help() -> str:
    """One line per registered policy: ``NAME  description``."""
    width = max(len(n) for n in _POLICIES)
    return "\n".join(f"  {n:<{width}}  {d}" for n, (_, d) in _POLICIES.items())


def make_policy(spec: str) -> Policy:
    """A policy from a registered name (``NAME`` or ``NAME:ARG``, see :func:`policy_names`),
    the path of a saved stable-baselines3 model (``.zip``) or a training directory (SB3 or
    RLlib, :func:`policies.learned.load_learned_policy`)."""
    name, _, arg = str(spec).partition(":")
    if name in _POLICIES:
        return _POLICIES[name][0](arg)
    if str(spec).endswith(".zip") or Path(spec).is_file():
        return SB3Policy(spec)
    if Path(spec).is_dir():  # a training DIR: SB3 (final_model.zip) or RLlib (checkpoint/)
        return load_learned_policy(spec)
    raise ValueError(
        f"unknown policy {spec!r}: use one of {policy_names()}, the path of a saved "
        f"stable-baselines3 model (.zip) or a training directory"
    )


def _no_argument(cls: Callable[[], Policy], name: str) -> PolicyFactory:
    def factory(arg: str) -> Policy:
        if arg:
            raise ValueError(f"policy {name!r} takes no argument, got {name}:{arg}")
        return cls()

    return factory


def _with_speed(cls: Callable[..., Policy], name: str, arg: str) -> Policy:
    """``cls()``, or ``cls(float(arg))`` for a spec ``NAME:SPEED``."""
    if not arg:
        return cls()
    try:
        return cls(float(arg))
    except ValueError as err:
        raise ValueError(f"policy '{name}:{arg}': {name}:SPEED needs a speed in (0, 1]") from err


def _wander(arg: str) -> Policy:
    from policies.fox import WanderPolicy

    return _with_speed(WanderPolicy, "wander", arg)


register_policy("fsm", _no_argument(FSMPolicy, "fsm"),
                "terrain-traversal state machine (Madhavan et al.)")
register_policy("random", _no_argument(RandomPolicy, "random"), "uniform random actions")
register_policy("seek", _no_argument(SeekTeammatePolicy, "seek"),
                "drive toward a teammate when uncertain")
register_policy("still", _no_argument(StandStillPolicy, "still"), "every robot stands still")
register_policy("wander", _wander, "Fox et al.'s wander behaviour; wander:SPEED sets the speed")


def _gather(arg: str) -> Policy:
    from policies.scripted import GatherPolicy

    return _no_argument(GatherPolicy, "gather")(arg)


def _infogain(arg: str) -> Policy:
    from policies.scripted import InfoGainPolicy

    return _no_argument(InfoGainPolicy, "infogain")(arg)


def _corridor(arg: str) -> Policy:
    from policies.scripted import CorridorPolicy

    return _with_speed(CorridorPolicy, "corridor", arg)


def _hypothesis(arg: str) -> Policy:
    from policies.scripted import HypothesisPolicy

    return _no_argument(HypothesisPolicy, "hypothesis")(arg)


register_policy("gather", _gather,
                "drive toward the teammates that can inform you (by the shared estimates)")
register_policy("infogain", _infogain,
                "greedy information seeking over motion primitives: least expected log det "
                "(EKF beliefs) or posterior entropy (MCL particle beliefs)")
register_policy("corridor", _corridor,
                "follow the free space ahead at full speed by the own scan; corridor:SPEED")
register_policy("hypothesis", _hypothesis,
                "hypothesis elimination with far targets: drive where the belief's modes "
                "predict different readings (MCL), localized robots meet the lost ones")
POLICY_NAMES = tuple(_POLICIES)  # the built-in names


def parse_overrides(pairs: list[str] | None) -> dict[str, Any]:
    """``["KEY=VALUE", ...]`` to a dict; values parse as Python literals, else stay strings."""
    out: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, raw = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"--set expects KEY=VALUE, got {pair!r}")
        try:
            out[key] = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            out[key] = raw
    return out


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
        },
    }


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
        One record per episode: the :data:`FIGURES`, ``seed``, ``steps``,
        ``team_return``, ``state_steps`` (robot-steps per FSM state, when the
        policy reports states), ``series`` (per-step arrays) and ``maps``
        (final estimated and true height grids, indexed ``[x, y]``).
    """
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be a positive integer, got {n_episodes!r}")
    if isinstance(policy, str):
        policy = make_policy(policy)
    env = coop_loc_env.parallel_env(scenario, **(overrides or {}))
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


def summarize(episodes: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean and (population) standard deviation over episodes of each of :data:`FIGURES`."""
    if not episodes:
        raise ValueError("summarize needs at least one episode, got []")
    out = {}
    for key in FIGURES:
        vals = np.array([ep[key] for ep in episodes], dtype=float)
        out[key] = {"mean": float(np.mean(vals)), "std": float(np.std(vals))}
    return out


def episode_figures(ep: dict[str, Any]) -> dict[str, Any]:
    """The JSON-serializable part of an episode record (no series or maps)."""
    return {k: v for k, v in ep.items() if k not in ("series", "maps")}


def report(scenario: str, policy: str, episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """The evaluation report: ``{"scenario", "policy", "episodes", "summary"}``."""
    return {
        "scenario": scenario,
        "policy": policy,
        "episodes": [episode_figures(ep) for ep in episodes],
        "summary": summarize(episodes),
    }


def write_json(data: dict[str, Any], path: str | Path) -> None:
    """Write ``data`` as JSON (NaN written as ``null``), creating parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if isinstance(x, (float, np.floating)):
            return float(x) if np.isfinite(x) else None
        if isinstance(x, np.integer):
            return int(x)
        return x

    path.write_text(json.dumps(clean(data), indent=2, allow_nan=False) + "\n")


def format_table(summary: dict[str, dict[str, float]], n_episodes: int) -> str:
    """A plain-text table of ``mean +/- std`` per figure."""
    labels = {
        "localization_error_m": "team localization error (m)",
        "coverage": "coverage (fraction)",
        "map_rmse_m": "map RMSE (m)",
        "collisions": "collisions",
        "tip_overs": "tip-overs",
    }
    width = max(len(v) for v in labels.values())
    lines = [f"{'figure':<{width}}  mean +/- std over {n_episodes} episode(s)"]
    lines.append("-" * (width + 34))
    for key in FIGURES:
        s = summary[key]
        lines.append(f"{labels[key]:<{width}}  {s['mean']:.4f} +/- {s['std']:.4f}")
    return "\n".join(lines)


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
    env = coop_loc_env.parallel_env(scenario, render_mode="rgb_array", **(overrides or {}))
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
