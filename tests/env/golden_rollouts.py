"""Stored regression rollouts: a few short seeded episodes per scenario and estimator.

``tests/env/test_golden_rollouts.py`` replays these cases and compares them with
``tests/data/golden_rollouts.npz``: observations, rewards and errors, and every
subsystem the observation does not carry in full (camera records with their
depth-from-motion ranges, the team terrain map, MCL particle statistics, MLE
relative poses, EKF covariances). When a change is *meant* to alter behaviour,
regenerate the file and commit it with the change:

    python tests/env/golden_rollouts.py

Actions come from NumPy's generator (not the action spaces' samplers), so the
stored episodes depend only on this project's code and its seeds. The file
stores statistics per step (sums, moments), not whole maps or particle sets,
so it stays small.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

GOLDEN_PATH = Path(__file__).resolve().parents[1] / "data" / "golden_rollouts.npz"

# name -> (scenario, overrides, episode seed, steps). Every scenario with its own
# estimator, and the outdoor scenario (camera, terrain, DGPS) with each estimator.
CASES: dict[str, tuple[str, dict, int, int]] = {
    "ekf_outdoor": ("outdoor_terrain", {"n_robots": 4}, 3, 40),
    "ekf_dgps_outage": ("dgps_outage", {}, 1, 30),
    "ekf_rendezvous": ("rendezvous", {}, 4, 25),
    "mcl_hallway": ("symmetric_hallway", {"n_robots": 3, "n_particles": 300}, 5, 25),
    "mcl_active_hallway": ("active_hallway", {"n_particles": 300}, 6, 20),
    "mcl_active_lattice": ("active_lattice", {"n_particles": 300}, 11, 20),
    "mcl_hexagon": ("hexagon", {"n_robots": 4, "n_particles": 300}, 7, 15),
    "mcl_outdoor": ("outdoor_terrain", {"estimator": "mcl", "n_particles": 300}, 8, 25),
    "mle_circuit": ("circuit", {}, 2, 30),
    "mle_dispersal": ("dispersal", {"n_robots": 6}, 9, 20),
    "mle_outdoor": ("outdoor_terrain", {"estimator": "mle"}, 10, 30),
}


def subsystem_state(env) -> dict[str, np.ndarray]:
    """This step's statistics of every subsystem, as fixed-shape float arrays.

    The only place of the golden rollouts that reads the env's state (when a
    refactor moves it, adapt this function and nothing else):

    * camera: ``env.camera_readings`` (public);
    * terrain map: ``env.terrain_map`` (public) and its ``robot_elevation()``;
    * MCL: ``env.beliefs.samples`` (public: each robot's particles, weights, ESS);
    * MLE: ``env.backends[k].mle.relative_poses()`` (the backend's pose graph);
    * EKF: ``env.estimated_covariances`` (public).

    Returns ``camera (n, 5)``: records, sums of range, range std, bearing and
    frames tracked; ``map (9,)``: mapped cells, sums of elevation, its square,
    confidence, confidence x elevation, cell-index x elevation (placement), object
    cells, and the sums of the robots' elevation estimates and variances;
    ``mcl (n, 7)``: weighted mean x, y, circular mean heading, weighted std x, y,
    ESS and particle count (NaN for robots of other estimators); ``mle (n, n, 3)``:
    estimated relative range, bearing, orientation between the MLE robots (NaN
    elsewhere); ``cov (n, 3, 3)``: every robot's belief covariance.
    """
    n = env.config.n_robots
    camera = np.zeros((n, 5))
    for i, agent in enumerate(env.possible_agents):
        records = env.camera_readings(agent)
        if records:
            camera[i] = [len(records), sum(r.range for r in records),
                         sum(r.range_std for r in records), sum(r.bearing for r in records),
                         sum(r.frames for r in records)]
    tmap = env.terrain_map
    mapped = tmap.mapped.ravel()
    elev = np.nan_to_num(tmap.elevation.ravel())
    conf = tmap.confidence.ravel()
    index = np.arange(elev.size) / elev.size
    robot_elev, robot_var = tmap.robot_elevation()
    terrain = np.array([
        mapped.sum(), elev.sum(), (elev**2).sum(), conf.sum(), (conf * elev).sum(),
        (index * elev).sum(), tmap.object_mask.sum(), robot_elev.sum(), robot_var.sum(),
    ])
    mcl = np.full((n, 7), np.nan)
    mle = np.full((n, n, 3), np.nan)
    for g, particles in env.beliefs.samples.items():
        p, w = np.asarray(particles.states, dtype=float), np.asarray(particles.weights)
        mean = w @ p[:, :2]
        std = np.sqrt(np.maximum(w @ (p[:, :2] - mean) ** 2, 0.0))
        heading = np.arctan2(w @ np.sin(p[:, 2]), w @ np.cos(p[:, 2]))
        mcl[g] = [mean[0], mean[1], heading, std[0], std[1], particles.ess, len(w)]
    for backend in env.backends:
        robots = np.asarray(backend.robots)
        if hasattr(backend, "mle"):
            mle[np.ix_(robots, robots)] = backend.mle.relative_poses()
    return {"camera": camera, "map": terrain, "mcl": mcl, "mle": mle,
            "cov": env.estimated_covariances}


def rollout(scenario: str, overrides: dict, seed: int, steps: int) -> dict[str, np.ndarray]:
    """Run one case; arrays of shape ``(steps + 1, ...)`` (reset first)."""
    import coop_loc_env

    env = coop_loc_env.parallel_env(scenario, **overrides)
    obs, infos = env.reset(seed=seed)
    agents = list(env.possible_agents)
    rng = np.random.default_rng(seed)
    observations = [np.stack([obs[a] for a in agents])]
    rewards = [np.zeros(len(agents))]
    errors = [np.array([infos[a]["position_error"] for a in agents])]
    states = [subsystem_state(env)]
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
        states.append(subsystem_state(env))
    env.close()
    out = {
        "obs": np.asarray(observations, dtype=np.float64),
        "rewards": np.asarray(rewards, dtype=np.float64),
        "position_error": np.asarray(errors, dtype=np.float64),
    }
    for key in states[0]:
        out[key] = np.asarray([s[key] for s in states], dtype=np.float64)
    return out


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
