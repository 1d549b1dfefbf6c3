"""Stored regression rollouts: seeded episodes per scenario, estimator and rare event.

``tests/env/test_golden_rollouts.py`` replays the :data:`CASES` and compares them
with the digests in ``tests/data/golden_rollouts.json``: per case and quantity
(actions, observations, rewards, errors, the sensor readings and every subsystem
the observation does not carry in full) an exact hash of the whole array, and per block of
:data:`BLOCK` steps its mean, a fixed random projection and its mean absolute
value. Equal hashes pass at once; otherwise the blocks are compared at
``RTOL`` (the last bits may move with another BLAS build), and the failure
names the case, the step range and the quantities that differ first. Next to
them the file keeps each case's :func:`figures`, among them the counts of the
rare decisions :class:`Probe` saw (the coverage test reads them); those counts
are measured against the estimators' thresholds, which a change of a threshold
moves without any change of behaviour, so they are recorded, not compared.

When a change is *meant* to alter behaviour, regenerate the file and commit it
with the change (every case, or the named ones):

    python tests/env/golden_rollouts.py [CASE ...]

Actions come from NumPy's generator (not the action spaces' samplers) or from
a scripted driver, so the stored episodes depend only on this project's code
and its seeds.
"""

from __future__ import annotations

import hashlib
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

GOLDEN_PATH = Path(__file__).resolve().parents[1] / "data" / "golden_rollouts.json"
BLOCK = 25  # steps per compared block (the failure message names the first block that differs)
RTOL = 1e-7  # relative tolerance of the block figures when the exact hashes differ


class Case(NamedTuple):
    """One stored episode: ``driver`` picks the actions (see :func:`drive`)."""

    scenario: str
    overrides: dict
    seed: int
    steps: int
    driver: str = "random"
    extras: dict | None = None  # set over the scenario's own extras


_WALL_START = ((1.0, 20.0, np.pi), (10.0, 8.0, 0.0), (20.0, 30.0, 0.5))
_MCL = {"estimator": "mcl", "n_particles": 300}

# Every scenario with its own estimator, the outdoor scenario (camera, terrain, DGPS)
# with each estimator, long episodes, and episodes built to reach the rare branches:
# multipath fixes, gate lock-out recoveries (a kidnapped robot, one pushing into a
# wall), false and conflicting detections between MCL robots, the scripted planners.
CASES: dict[str, Case] = {
    "ekf_outdoor": Case("outdoor_terrain", {"n_robots": 4}, 3, 40),
    "ekf_dgps_outage": Case("dgps_outage", {}, 1, 30),
    "ekf_rendezvous": Case("rendezvous", {}, 4, 25),
    "mcl_hallway": Case("symmetric_hallway", {"n_robots": 3, "n_particles": 300}, 5, 25),
    "mcl_active_hallway": Case("active_hallway", {"n_particles": 300}, 6, 20),
    "mcl_active_lattice": Case("active_lattice", {"n_particles": 300}, 11, 20),
    "mcl_hexagon": Case("hexagon", {"n_robots": 4, "n_particles": 300}, 7, 15),
    "mcl_outdoor": Case("outdoor_terrain", _MCL, 8, 25),
    "mle_circuit": Case("circuit", {}, 2, 30),
    "mle_dispersal": Case("dispersal", {"n_robots": 6}, 9, 20),
    "mle_outdoor": Case("outdoor_terrain", {"estimator": "mle"}, 10, 30),
    # long episodes at the scenarios' defaults
    "ekf_outdoor_long": Case("outdoor_terrain", {"n_robots": 6}, 11, 400),
    "ekf_rendezvous_long": Case("rendezvous", {}, 12, 300),
    "ekf_dgps_outage_long": Case("dgps_outage", {}, 13, 300),
    "mle_circuit_long": Case("circuit", {}, 14, 300),
    # rare events
    "ekf_multipath": Case("outdoor_terrain", {"n_robots": 6, "gps_multipath_prob": 0.3}, 15, 300),
    # outliers near the truth: runs of rejections whose agreement is close to the
    # GateMonitor's AGREE_PROB threshold (one decides a recovery at step 160)
    "ekf_multipath_agreement": Case("outdoor_terrain", {
        "n_robots": 6, "gps_multipath_prob": 0.5, "gps_multipath_std": 0.8}, 41, 200),
    "ekf_kidnapped": Case("outdoor_terrain", {"n_robots": 4}, 16, 120, "kidnap"),
    "ekf_wall_push": Case("outdoor_terrain", {"n_robots": 3, "start_poses": _WALL_START},
                          17, 300, "wall"),
    "ekf_false_detections": Case("rendezvous", {"false_positive_prob": 0.4}, 18, 300),
    "mcl_false_detections": Case("active_hallway", {"false_positive_prob": 0.3}, 19, 120),
    "mcl_kidnapped": Case("active_hallway", {}, 20, 150, "kidnap"),
    # each particle scenario at its own default particle count, one on the dict observation
    "mcl_active_hallway_default": Case("active_hallway", {"max_cycles": 300}, 21, 300),
    "mcl_outdoor_default": Case("outdoor_terrain", {"estimator": "mcl"}, 30, 60),
    "mcl_hallway_default": Case("symmetric_hallway", {}, 22, 60),
    "mcl_hexagon_default": Case("hexagon", {}, 23, 6),
    "mcl_active_lattice_default": Case("active_lattice", {}, 33, 40),
    "mcl_dict_obs": Case("active_hallway", {"obs_format": "dict", "n_particles": 500}, 24, 60),
    # the scripted planners' decisions (their actions are a digested quantity)
    "plan_hypothesis": Case("active_hallway", {"n_particles": 400}, 25, 80, "policy:hypothesis"),
    "plan_hypothesis_long": Case("active_hallway", {"n_particles": 300}, 32, 240,
                                 "policy:hypothesis"),
    "plan_corridor": Case("active_hallway", {"n_particles": 300}, 26, 60, "policy:corridor"),
    "plan_infogain_mcl": Case("active_hallway", {"n_particles": 300}, 27, 40, "policy:infogain"),
    "plan_infogain_ekf": Case("outdoor_terrain", {"n_robots": 4}, 28, 100, "policy:infogain"),
    "plan_fsm": Case("outdoor_terrain", {"n_robots": 6}, 39, 500, "policy:fsm"),
    # the symmetric copies sharing the top mode's weight (an option, off by default)
    "mcl_calibrated_copies": Case("active_hallway", {"n_particles": 300}, 42, 60,
                                  extras={"mcl_calibrated_copies": True}),
}


# ---------------------------------------------------------------- what is recorded
def subsystem_state(env) -> dict[str, np.ndarray]:
    """This step's statistics of every subsystem, as fixed-shape float arrays.

    One of the two places of the golden rollouts that read the env's state (with
    :class:`Probe`; when a refactor moves it, adapt these and nothing else):

    * camera: ``env.camera_readings`` (public);
    * terrain map: ``env.terrain_map`` (public) and its ``robot_elevation()``;
    * MCL: ``env.beliefs.samples`` (public: each robot's particles, weights, ESS);
    * MLE: ``env.backends[k].mle.relative_poses()`` (the backend's pose graph);
    * EKF: ``env.estimated_covariances`` (public);
    * readings: ``env.last_readings`` (public): DGPS fixes, compass, scans, detections.

    Returns ``camera (n, 5)``: records, sums of range, range std, bearing and
    frames tracked; ``map (9,)``: mapped cells, sums of elevation, its square,
    confidence, confidence x elevation, cell-index x elevation (placement), object
    cells, and the sums of the robots' elevation estimates and variances;
    ``mcl (n, 7)``: weighted mean x, y, circular mean heading, weighted std x, y,
    ESS and particle count (NaN for robots of other estimators); ``mle (n, n, 3)``:
    estimated relative range, bearing, orientation between the MLE robots (NaN
    elsewhere); ``cov (n, 3, 3)``: every robot's belief covariance; ``gps (n, 4)``:
    fix, x, y, variance; ``compass (n, 2)``; ``ranges (n, beams)``; ``detections
    (d, 5)``: observer, target, range, bearing, orientation (padded with NaN to
    ``2 n`` rows).
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
    out = {"camera": camera, "map": terrain, "mcl": mcl, "mle": mle,
           "cov": env.estimated_covariances}
    out.update(_readings(env.last_readings, n))
    return out


def _readings(r, n: int) -> dict[str, np.ndarray]:
    """The step's sensor readings as fixed-shape arrays (zeros before the first step)."""
    if r is None:
        return {"gps": np.zeros((n, 4)), "compass": np.zeros((n, 2)),
                "ranges": np.zeros((n, 1)), "detections": np.full((2 * n, 5), np.nan)}
    fix = r.gps_mask
    gps = np.column_stack([fix, np.where(fix[:, None], r.gps_xy, 0.0),
                           np.where(fix, r.gps_var, 0.0)])
    compass = np.column_stack([r.compass_mask, np.where(r.compass_mask, r.compass, 0.0)])
    ranges = np.where(r.range_mask[:, None], np.nan_to_num(r.ranges, nan=-1.0), 0.0)
    det = r.detections
    rows = np.column_stack([det.observer, det.target, det.z]) if len(det) else np.zeros((0, 5))
    detections = np.full((max(2 * n, len(rows)), 5), np.nan)
    detections[: len(rows)] = rows
    return {"gps": gps, "compass": compass, "ranges": ranges, "detections": detections}


# Columns of the per-step ``events`` quantity (counts of the step's decisions, :class:`Probe`).
EVENTS = (
    "gate_tests",  # chi-square gate decisions of the EKFs (DGPS, compass, detections)
    "gate_rejections",
    "gate_rejections_near",  # rejected within 10 % of the threshold (d2 / threshold <= 1.1)
    "gate_accepts_near",  # accepted within 10 % of it (d2 / threshold >= 0.9)
    "agreement_tests",  # GateMonitor: does a rejection agree with the run's previous one?
    "agreement_near",  # its statistic within 10 % of the AGREE_PROB threshold
    "recoveries",  # EKF lock-out recoveries (GateMonitor.recoveries, summed)
    "assessments",  # MCL detection consistency decisions (assess_detection)
    "confident_below",  # of a confident target with a Bayes factor < min_bayes_factor
    "confident_above",  # ... >= min_bayes_factor
    "bayes_factor_near",  # confident target, factor within a factor 2 of min_bayes_factor
    "mode_mass_near",  # the target's main-mode mass within 10 % of confident_mass
    "conflicts",  # assessments that found a conflict
    "multipath_fixes",  # DGPS fixes off the truth by > 5.3 reported stds (chi2 2 dof 1e-6)
    "false_detections",  # detections whose ``genuine`` flag is False
)
_MULTIPATH_D2 = 27.63  # chi-square, 2 dof, tail 1e-6: no ordinary fix is this far off


class Probe:
    """Counts the rare decisions of a rollout (the :data:`EVENTS`), per step.

    Wraps, for the rollout only, the public decision points of the estimators:
    each EKF backend's ``PoseEKF._gate`` and ``monitor.record`` (on the instance,
    after ``reset``) and ``detection_transfer.assess_detection`` (the module
    function, restored by :meth:`close`). The wrappers return what they wrap:
    the rollout is unchanged.
    """

    def __init__(self, env) -> None:
        from estimators import gating
        from estimators.mcl import detection_transfer

        self.env = env
        self.counts = np.zeros(len(EVENTS))
        self._gating = gating
        self._module = detection_transfer
        self._assess = detection_transfer.assess_detection
        detection_transfer.assess_detection = self._wrap_assess(self._assess)
        self._monitors = []
        for backend in env.backends:
            ekf = getattr(backend, "ekf", None)
            if ekf is not None and hasattr(ekf, "monitor"):
                ekf._gate = self._wrap_gate(ekf, ekf._gate)
                ekf.monitor.record = self._wrap_record(ekf.monitor, ekf.monitor.record)
                self._monitors.append(ekf.monitor)
        self._recoveries = self._total_recoveries()

    def _add(self, name: str, k: int | float) -> None:
        self.counts[EVENTS.index(name)] += k

    def _wrap_gate(self, ekf, gate: Callable) -> Callable:
        def wrapped(d2, dof, gate_prob):
            ok = gate(d2, dof, gate_prob)
            prob = ekf.gate_prob if gate_prob is None else gate_prob
            if prob < 1.0 and len(d2):
                ratio = np.asarray(d2) / self._gating.chi2_threshold(prob, dof)
                self._add("gate_tests", len(ratio))
                self._add("gate_rejections", np.count_nonzero(~ok))
                self._add("gate_rejections_near", np.count_nonzero(~ok & (ratio <= 1.1)))
                self._add("gate_accepts_near", np.count_nonzero(ok & (ratio >= 0.9)))
            return ok
        return wrapped

    def _wrap_record(self, monitor, record: Callable) -> Callable:
        last: dict[Any, tuple[np.ndarray, np.ndarray]] = {}

        def wrapped(channel, idx, accepted, nu=None, s=None, angles=()):
            if nu is not None and s is not None:
                counts = monitor.counts.get(channel)
                prev = counts[idx] if counts is not None else np.zeros(len(idx), dtype=int)
                m = nu.shape[1]
                if channel not in last or last[channel][0].shape[1] != m:
                    last[channel] = (np.zeros((monitor.n, m)), np.zeros((monitor.n, m, m)))
                rejected = ~np.asarray(accepted, dtype=bool)
                rows = np.nonzero(rejected & (prev > 0))[0]
                if len(rows):
                    d = nu[rows] - last[channel][0][idx[rows]]
                    for a in angles:
                        d[:, a] = (d[:, a] + np.pi) % (2 * np.pi) - np.pi
                    joint = s[rows] + last[channel][1][idx[rows]]
                    d2 = np.einsum("ki,kij,kj->k", d, np.linalg.pinv(joint), d)
                    ratio = d2 / self._gating.chi2_threshold(self._gating.AGREE_PROB, m)
                    self._add("agreement_tests", len(rows))
                    self._add("agreement_near", np.count_nonzero(np.abs(ratio - 1) <= 0.1))
                last[channel][0][idx[rejected]] = nu[rejected]
                last[channel][1][idx[rejected]] = s[rejected]
            return record(channel, idx, accepted, nu, s, angles)
        return wrapped

    def _wrap_assess(self, assess: Callable) -> Callable:
        def wrapped(target_xy, target_weights, factors, bayes_factor, config, hypotheses=None):
            out = assess(target_xy, target_weights, factors, bayes_factor, config, hypotheses)
            self._add("assessments", 1)
            if out.confident:
                below = out.bayes_factor < config.min_bayes_factor
                self._add("confident_below" if below else "confident_above", 1)
                ratio = out.bayes_factor / config.min_bayes_factor
                self._add("bayes_factor_near", 0.5 <= ratio <= 2.0)
            self._add("mode_mass_near", abs(out.mode_mass / config.confident_mass - 1) <= 0.1)
            self._add("conflicts", out.conflict)
            return out
        return wrapped

    def _total_recoveries(self) -> int:
        return sum(m.recoveries for m in self._monitors)

    def step(self) -> np.ndarray:
        """This step's counts (call after each ``env.step``); starts the next step's."""
        total = self._total_recoveries()
        self._add("recoveries", total - self._recoveries)
        self._recoveries = total
        r = self.env.last_readings
        if r is not None:
            fix = r.gps_mask
            if fix.any():
                off = r.gps_xy[fix] - self.env.world.poses[fix, :2]
                d2 = (off**2).sum(axis=1) / r.gps_var[fix]
                self._add("multipath_fixes", np.count_nonzero(d2 > _MULTIPATH_D2))
            self._add("false_detections", np.count_nonzero(~r.detections.genuine))
        out, self.counts = self.counts, np.zeros(len(EVENTS))
        return out

    def close(self) -> None:
        self._module.assess_detection = self._assess


# ---------------------------------------------------------------- how actions are chosen
def drive(case: Case, env, rng: np.random.Generator) -> Callable[[int, dict], dict]:
    """``act(t, obs) -> actions`` of ``case.driver``:

    * ``random``: uniform draws of ``rng``;
    * ``policy:SPEC``: the scripted policy ``SPEC`` (reset with the case's seed);
    * ``kidnap``: random, and at step ``steps // 3`` robot 0's body is carried to the
      point mirrored through the centre of the world (its estimator is not told);
    * ``wall``: random, but robot 0 drives full speed ahead (into the wall it faces).
    """
    agents = list(env.possible_agents)

    def random_actions(t: int, obs: dict) -> dict:
        draw = rng.uniform(-1.0, 1.0, size=(len(agents), 2)).astype(np.float32)
        return {a: draw[i] for i, a in enumerate(agents) if a in env.agents}

    if case.driver == "random":
        return random_actions
    if case.driver.startswith("policy:"):
        from policies.learning.loader import make_policy

        policy = make_policy(case.driver.partition(":")[2])
        policy.reset(env, seed=case.seed)
        return lambda t, obs: policy.act(obs)
    if case.driver == "kidnap":
        def kidnap(t: int, obs: dict) -> dict:
            if t == case.steps // 3:
                w, h = env.config.world_size
                x, y = env.world.poses[0, :2]
                env.world.bodies[0].position = (float(w - x), float(h - y))
            return random_actions(t, obs)
        return kidnap
    if case.driver == "wall":
        def wall(t: int, obs: dict) -> dict:
            actions = random_actions(t, obs)
            actions[agents[0]] = np.array([1.0, 0.0], dtype=np.float32)
            return actions
        return wall
    raise ValueError(f"unknown driver {case.driver!r}")


def _flat(obs: dict, agents: list[str], template: np.ndarray | None) -> np.ndarray:
    """Every agent's observation as one float row (a dict observation's entries in key
    order); NaN rows for agents that are gone."""
    rows = []
    for a in agents:
        o = obs.get(a)
        if o is None:
            rows.append(np.full_like(template, np.nan))
        elif isinstance(o, dict):
            rows.append(np.concatenate([np.ravel(o[k]).astype(float) for k in sorted(o)]))
        else:
            rows.append(np.ravel(o).astype(float))
    return np.stack(rows)


def rollout(case: Case) -> dict[str, np.ndarray]:
    """Run one case; arrays of shape ``(steps + 1, ...)`` (reset first)."""
    import coop_loc_env

    overrides = case.overrides
    if case.extras is not None:
        extras = {**coop_loc_env.make_config(case.scenario).extras, **case.extras}
        overrides = {**overrides, "extras": extras}
    env = coop_loc_env.parallel_env(case.scenario, **overrides)
    obs, infos = env.reset(seed=case.seed)
    agents = list(env.possible_agents)
    probe = Probe(env)
    try:
        act = drive(case, env, np.random.default_rng(case.seed))
        observations = [_flat(obs, agents, None)]
        template = observations[0][0]
        zero_action = np.zeros((len(agents), 2))
        actions_taken = [zero_action]
        rewards = [np.zeros(len(agents))]
        errors = [np.array([infos[a]["position_error"] for a in agents])]
        states = [subsystem_state(env)]
        events = [probe.step()]
        for t in range(case.steps):
            if not env.agents:
                break
            actions = act(t, obs)
            obs, rew, _, _, infos = env.step(actions)
            actions_taken.append(np.array([actions.get(a, (np.nan, np.nan)) for a in agents],
                                          dtype=float))
            observations.append(_flat(obs, agents, template))
            rewards.append(np.array([rew.get(a, np.nan) for a in agents]))
            errors.append(np.array([infos[a]["position_error"] if a in infos else np.nan
                                    for a in agents]))
            states.append(subsystem_state(env))
            events.append(probe.step())
    finally:
        probe.close()
        env.close()
    out = {
        "actions": np.asarray(actions_taken, dtype=np.float64),
        "obs": np.asarray(observations, dtype=np.float64),
        "rewards": np.asarray(rewards, dtype=np.float64),
        "position_error": np.asarray(errors, dtype=np.float64),
        "events": np.asarray(events, dtype=np.float64),
    }
    for key in states[0]:
        if key == "detections":  # a step may hold more detections than 2 n: pad to the most
            rows = max(len(s[key]) for s in states)
            out[key] = np.stack([np.pad(s[key], ((0, rows - len(s[key])), (0, 0)),
                                        constant_values=np.nan) for s in states])
        elif key == "ranges":
            width = max(s[key].shape[1] for s in states)
            out[key] = np.stack([np.pad(s[key], ((0, 0), (0, width - s[key].shape[1])))
                                 for s in states])
        else:
            out[key] = np.asarray([s[key] for s in states], dtype=np.float64)
    return out


# ---------------------------------------------------------------- digests
def _weights(size: int) -> np.ndarray:
    """The fixed random projection of a block of ``size`` values."""
    return np.random.default_rng(size).standard_normal(size)


def digest(values: np.ndarray) -> dict[str, Any]:
    """The stored digest of one quantity ``(steps + 1, ...)``: shape, the SHA-256 of its
    bytes and of its non-finite mask, and per block of :data:`BLOCK` steps ``[mean,
    projection, mean |value|]`` of its finite values (non-finite ones count as 0)."""
    values = np.ascontiguousarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    clean = np.where(finite, values, 0.0)
    blocks = []
    for start in range(0, len(values), BLOCK):
        b = clean[start:start + BLOCK].ravel()
        if b.size == 0:
            blocks.append([0.0, 0.0, 0.0])
            continue
        figures = (b.mean(), _weights(b.size) @ b, np.abs(b).mean())
        blocks.append([float(f"{x:.12g}") for x in figures])  # 12 digits: far below RTOL
    return {
        "shape": list(values.shape),
        "sha256": hashlib.sha256(values.tobytes()).hexdigest()[:32],
        "nonfinite": hashlib.sha256(np.packbits(~finite).tobytes()).hexdigest()[:16],
        "blocks": blocks,
    }


def compare(case: str, got: dict[str, np.ndarray], stored: dict[str, dict]) -> str | None:
    """``None`` when ``got`` matches the ``stored`` digests of ``case``; otherwise what
    differs first: the step range and the quantities that differ there, with figures."""
    if set(got) != set(stored):
        return f"{case}: quantities {sorted(got)} != stored {sorted(stored)}"
    first: dict[int, list[str]] = {}
    for key, values in got.items():
        want = stored[key]
        d = digest(values)
        if d["sha256"] == want["sha256"]:
            continue
        if d["shape"] != want["shape"]:
            first.setdefault(-1, []).append(f"{key}: shape {d['shape']} != stored {want['shape']}")
            continue
        if d["nonfinite"] != want["nonfinite"]:
            bad = np.nonzero(~np.isfinite(values).reshape(len(values), -1).all(axis=1))[0]
            first.setdefault(-1, []).append(
                f"{key}: other non-finite entries (now at steps {bad[:5].tolist()}...)")
            continue
        for b, (g, w) in enumerate(zip(d["blocks"], want["blocks"], strict=True)):
            size = min(BLOCK, len(values) - b * BLOCK) * int(np.prod(values.shape[1:]))
            tol_mean = RTOL * w[2] + 1e-12
            tol_proj = RTOL * w[2] * float(np.abs(_weights(size)).sum()) + 1e-12
            if abs(g[0] - w[0]) > tol_mean or abs(g[1] - w[1]) > tol_proj:
                first.setdefault(b, []).append(
                    f"{key} (mean {g[0]:.6g}, stored {w[0]:.6g}; mean |x| {g[2]:.6g}, "
                    f"stored {w[2]:.6g})")
                break
    if not first:
        return None
    b = min(first)
    where = "shape or non-finite entries" if b < 0 else (
        f"steps {b * BLOCK}-{min((b + 1) * BLOCK, len(next(iter(got.values())))) - 1}")
    return (f"{case} differs from the stored rollout first at {where}: "
            + "; ".join(first[b])
            + " (regenerate with `python tests/env/golden_rollouts.py " + case + "` if intended)")


def event_totals(values: np.ndarray) -> dict[str, int]:
    """The case's total count of each of :data:`EVENTS` (from its ``events`` quantity)."""
    return {name: int(round(v)) for name, v in zip(EVENTS, values.sum(axis=0), strict=True)}


def figures(got: dict[str, np.ndarray]) -> dict[str, int]:
    """A case's decoded figures (stored next to its digests, read by the coverage test):
    the :func:`event_totals`, camera records and those tracked over more than one frame,
    mapped cells at the start and the end, MCL robots and MLE robot pairs with estimates,
    steps run."""
    camera, mapped = got["camera"], got["map"][:, 0]
    return {
        **event_totals(got["events"]),
        "camera_records": int(camera[..., 0].sum()),
        "camera_multi_frame": int((camera[..., 4] > camera[..., 0]).sum()),
        "mapped_start": int(mapped[0]),
        "mapped_end": int(mapped[-1]),
        "mcl_robots": int(np.isfinite(got["mcl"][-1, :, 0]).sum()),
        "mle_pairs": int(np.isfinite(got["mle"][-1, :, :, 0]).sum()),
        "steps": len(got["actions"]) - 1,
    }


def record(names: list[str] | None = None) -> dict[str, Any]:
    """The digests of ``names`` (every case by default), merged into the stored file."""
    data = load() if GOLDEN_PATH.exists() else {"block": BLOCK, "cases": {}}
    if data.get("block") != BLOCK:
        data, names = {"block": BLOCK, "cases": {}}, None
    for name in names or list(CASES):
        got = rollout(CASES[name])
        data["cases"][name] = {
            "figures": figures(got),
            "quantities": {key: digest(value) for key, value in got.items()
                           if key != "events"},
        }
    data["cases"] = {k: data["cases"][k] for k in CASES if k in data["cases"]}
    return data


def load() -> dict[str, Any]:
    return json.loads(GOLDEN_PATH.read_text())


def main(argv: list[str] | None = None) -> int:
    names = list(sys.argv[1:] if argv is None else argv)
    unknown = [n for n in names if n not in CASES]
    if unknown:
        print(f"unknown case {unknown[0]!r}; cases: {', '.join(CASES)}", file=sys.stderr)
        return 2
    data = record(names or None)
    GOLDEN_PATH.parent.mkdir(parents=True, exist_ok=True)
    GOLDEN_PATH.write_text(json.dumps(data, separators=(",", ":")) + "\n")
    print(f"wrote {GOLDEN_PATH} ({GOLDEN_PATH.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    raise SystemExit(main())
