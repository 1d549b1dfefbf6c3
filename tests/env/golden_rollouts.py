"""Stored regression rollouts: a few short seeded episodes per estimator.

``tests/env/test_golden_rollouts.py`` replays these cases and compares observations,
rewards and errors with ``tests/data/golden_rollouts.npz``. When a change is
*meant* to alter behaviour, regenerate the file and commit it with the change:

    python tests/env/golden_rollouts.py

Actions come from NumPy's generator (not the action spaces' samplers), so the
stored episodes depend only on this project's code and its seeds.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

GOLDEN_PATH = Path(__file__).resolve().parents[1] / "data" / "golden_rollouts.npz"

# name -> (scenario, overrides, episode seed, steps)
CASES: dict[str, tuple[str, dict, int, int]] = {
    "ekf_outdoor": ("outdoor_terrain", {"n_robots": 4}, 3, 40),
    "ekf_dgps_outage": ("dgps_outage", {}, 1, 30),
    "mcl_hallway": ("symmetric_hallway", {"n_robots": 3, "n_particles": 300}, 5, 25),
    "mle_circuit": ("circuit", {}, 2, 30),
}


def rollout(scenario: str, overrides: dict, seed: int, steps: int) -> dict[str, np.ndarray]:
    """Run one case; arrays of shape ``(steps + 1, n_agents, ...)`` (reset first)."""
    import coop_loc_env

    env = coop_loc_env.parallel_env(scenario, **overrides)
    obs, infos = env.reset(seed=seed)
    agents = list(env.possible_agents)
    rng = np.random.default_rng(seed)
    observations = [np.stack([obs[a] for a in agents])]
    rewards = [np.zeros(len(agents))]
    errors = [np.array([infos[a]["position_error"] for a in agents])]
    for _ in range(steps):
        draw = rng.uniform(-1.0, 1.0, size=(len(agents), 2)).astype(np.float32)
        actions = {a: draw[i] for i, a in enumerate(agents) if a in env.agents}
        if not actions:
            break
        obs, rew, _, _, infos = env.step(actions)
        observations.append(np.stack([obs.get(a, np.full_like(observations[0][0], np.nan))
                                      for a in agents]))
        rewards.append(np.array([rew.get(a, np.nan) for a in agents]))
        errors.append(np.array([infos[a]["position_error"] if a in infos else np.nan
                                for a in agents]))
    env.close()
    return {
        "obs": np.asarray(observations, dtype=np.float64),
        "rewards": np.asarray(rewards, dtype=np.float64),
        "position_error": np.asarray(errors, dtype=np.float64),
    }


def record_all() -> dict[str, np.ndarray]:
    """Every case's arrays, keyed ``<case>/<array>``."""
    out: dict[str, np.ndarray] = {}
    for name, (scenario, overrides, seed, steps) in CASES.items():
        for key, value in rollout(scenario, overrides, seed, steps).items():
            out[f"{name}/{key}"] = value
    return out


def main() -> int:
    GOLDEN_PATH.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(GOLDEN_PATH, **record_all())
    print(f"wrote {GOLDEN_PATH} ({GOLDEN_PATH.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    raise SystemExit(main())
