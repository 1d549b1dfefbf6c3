"""Stored regression rollout of the batched env: three worlds of ``rendezvous`` with
episodes of 12 steps, so every world resets itself twice within the 30 stored steps
(the same-step autoreset, its final observations and the next episode's seeds are
pinned with the rest). Digests as in :mod:`golden_rollouts`; regenerate, when a
change is meant to alter behaviour, with ``python tests/env/test_golden_vector_env.py``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from golden_rollouts import compare, digest  # noqa: E402

import coop_loc_env  # noqa: E402

PATH = Path(__file__).resolve().parents[1] / "data" / "golden_vector_env.json"
WORLDS, STEPS, MAX_CYCLES, SEED = 3, 30, 12, 40


def rollout() -> dict[str, np.ndarray]:
    """The batch's arrays over the rollout, ``(STEPS + 1, ...)`` (reset first)."""
    env = coop_loc_env.vector_env("rendezvous", num_envs=WORLDS, max_cycles=MAX_CYCLES)
    obs, _ = env.reset(seed=SEED)
    rng = np.random.default_rng(SEED)
    n = env.n_robots
    out: dict[str, list[np.ndarray]] = {
        "actions": [np.zeros((WORLDS, n, 2))], "obs": [obs], "rewards": [np.zeros((WORLDS, n))],
        "terminated": [np.zeros((WORLDS, n))], "truncated": [np.zeros((WORLDS, n))],
        "position_error": [np.zeros((WORLDS, n))], "final_obs": [np.zeros_like(obs)],
        "est_pose": [env.estimated_poses],
    }
    try:
        for _ in range(STEPS):
            act = rng.uniform(-1, 1, (WORLDS, n, 2))
            obs, rew, term, trunc, infos = env.step(act)
            ended = infos.get("_final_obs", np.zeros(WORLDS, bool))
            final = np.zeros_like(obs)
            if ended.any():
                final[ended] = np.asarray(infos["final_obs"])[ended]
            for key, value in (("actions", act), ("obs", obs), ("rewards", rew),
                               ("terminated", term), ("truncated", trunc),
                               ("position_error", infos["position_error"]),
                               ("final_obs", final), ("est_pose", env.estimated_poses)):
                out[key].append(np.asarray(value, dtype=np.float64))
    finally:
        env.close()
    return {key: np.asarray(values, dtype=np.float64) for key, values in out.items()}


def test_batched_rollout_matches_the_stored_digests():
    got = rollout()
    assert int(got["truncated"][:, :, 0].sum()) == 2 * WORLDS  # two episode ends per world
    stored = json.loads(PATH.read_text())
    message = compare("vector_env_rendezvous", got, stored["quantities"])
    assert message is None, message.replace(
        "tests/env/golden_rollouts.py vector_env_rendezvous", "tests/env/test_golden_vector_env.py")


if __name__ == "__main__":
    data = {"quantities": {k: digest(v) for k, v in rollout().items()}}
    PATH.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {PATH}")
