"""Does the EKF belief stay honest when robots misbehave? Prints figures.

Three probes on ``outdoor_terrain`` with the EKF backend:

* ``forward``: 4 robots driving forward (linear action uniform in [0.2, 1], turn
  in [-0.5, 0.5]) for 1000 steps, seeds 3 and 4: share of belief samples whose
  NEES exceeds the 99.9 % chi-square bound (3 dof), median and max position error.
* ``half_gps``: a team alternating a full sensor suite with robots without DGPS
  (4 robots, random starts, ``init_pos_std=2``, no steep patches, random
  actions), 8 seeds x 400 steps: the largest one-step rise of any robot's
  position error.
* ``wall``: robot 0 drives at full speed into the world boundary for 60 s, then
  turns away and drives freely: NEES share below the bound while blocked and the
  time after leaving the wall until its position error is below 0.5 m.
* ``kidnapped_log`` (with ``--mrclam DATASET``): the MR.CLAM replay (600 s) with
  robot 1 started 3.6 m from its true pose but the usual small covariance, with
  and without the gate lock-out recovery: its mean error, the time until it is
  within 0.5 m, and the rejected readings per robot.

    python scripts/bench/belief_honesty.py [--probe forward half_gps wall] [--json PATH]
    python scripts/bench/belief_honesty.py --probe kidnapped_log \
        --mrclam /work/shared/data/mrclam/MRCLAM_Dataset6
"""

from __future__ import annotations

import json
import math
import sys

import numpy as np

import coop_loc_env
from coop_loc_env import RobotSpec
from coop_loc_env.cli import ScriptParser, run_script

NEES_BOUND = 16.266  # chi-square 99.9 % quantile, 3 dof


def _nees(info: dict) -> float:
    d = np.asarray(info["est_pose"], dtype=float) - np.asarray(info["true_pose"], dtype=float)
    d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
    return float(d @ np.linalg.solve(np.asarray(info["pose_cov"], dtype=float), d))


def forward(seeds=(3, 4), steps: int = 1000) -> dict:
    """Forward driving: NEES share above the bound, median and max position error."""
    nees, err = [], []
    for seed in seeds:
        env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, max_cycles=steps)
        env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        while env.agents:
            act = {a: np.array([rng.uniform(0.2, 1.0), rng.uniform(-0.5, 0.5)]) for a in env.agents}
            _, _, _, _, infos = env.step(act)
            for info in infos.values():
                nees.append(_nees(info))
                err.append(info["position_error"])
    nees, err = np.array(nees), np.array(err)
    return {
        "samples": len(err),
        "nees_above_bound": float(np.mean(nees > NEES_BOUND)),
        "median_error_m": float(np.median(err)),
        "max_error_m": float(err.max()),
    }


def half_gps(seeds=range(8), steps: int = 400) -> dict:
    """Half the team without DGPS: the largest one-step rise of a robot's position error."""
    worst, where = 0.0, None
    for seed in seeds:
        env = coop_loc_env.parallel_env(
            "outdoor_terrain", team=(RobotSpec(), RobotSpec(has_gps=False)), n_robots=4,
            start_region=None, init_pos_std=2.0, steep_patches=0, max_cycles=steps,
        )
        _, infos = env.reset(seed=seed)
        prev = {a: i["position_error"] for a, i in infos.items()}
        rng = np.random.default_rng(1000 + seed)
        t = 0
        while env.agents:
            act = {a: rng.uniform(-1.0, 1.0, 2) for a in env.agents}
            _, _, _, _, infos = env.step(act)
            t += 1
            for a, info in infos.items():
                rise = info["position_error"] - prev[a]
                if rise > worst:
                    worst, where = rise, (seed, t, a)
                prev[a] = info["position_error"]
    return {"max_error_rise_m": worst, "at_seed_step_agent": where}


def wall(seed: int = 3, blocked_s: float = 60.0, free_s: float = 40.0) -> dict:
    """Robot 0 pushes against the west boundary, then turns away and drives freely."""
    start = ((1.0, 20.0, math.pi), (10.0, 8.0, 0.0), (12.0, 10.0, 1.0), (8.0, 12.0, 2.0))
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, start_poses=start,
                                    max_cycles=100000, tip_over_terminates=False)
    env.reset(seed=seed)
    dt = env.config.dt
    rng = np.random.default_rng(seed)
    n_block, n_free = round(blocked_s / dt), round(free_s / dt)
    turn_steps = round(math.pi / env.config.max_turn_rate / dt)
    blocked_nees, recovered_at, errors = [], None, []
    prev_x = None
    for t in range(n_block + n_free):
        act = {a: np.array([rng.uniform(0.2, 1.0), rng.uniform(-0.5, 0.5)]) for a in env.agents}
        if t < n_block:
            act["robot_0"] = np.array([1.0, 0.0])
        elif t < n_block + turn_steps:
            act["robot_0"] = np.array([0.0, 1.0])
        else:
            act["robot_0"] = np.array([1.0, rng.uniform(-0.3, 0.3)])
        _, _, _, _, infos = env.step(act)
        info = infos["robot_0"]
        x = info["true_pose"][0]
        if t < n_block and prev_x is not None and abs(x - prev_x) < 0.1 * env.config.max_speed * dt:
            blocked_nees.append(_nees(info))
        prev_x = x
        errors.append(info["position_error"])
        if t >= n_block and recovered_at is None and info["position_error"] < 0.5:
            recovered_at = (t - n_block + 1) * dt
    b = np.array(blocked_nees)
    return {
        "blocked_steps": len(b),
        "blocked_nees_below_bound": float(np.mean(b < NEES_BOUND)) if len(b) else None,
        "error_at_leaving_m": float(errors[n_block - 1]),
        "max_error_blocked_m": float(max(errors[:n_block])),
        "seconds_to_below_0.5m_after_leaving": recovered_at,
        "max_error_last_20s_m": float(max(errors[-round(20 / dt):])),
    }


def kidnapped_log(dataset: str, offset=(3.0, -2.0), duration: float = 600.0) -> dict:
    """MR.CLAM replay with robot 1's start moved by ``offset``, recovery on and off."""
    import estimators.replay.runner as replay_mod
    from estimators.mrclam import load_mrclam
    from estimators.replay import load_noise_parameters
    from estimators.team_ekf import TeamEKF

    data = load_mrclam(dataset)
    params = load_noise_parameters()
    out = {}

    class Kidnapped(TeamEKF):
        recover_after: int | None = 3

        def __init__(self, tracks, mean, cov, t0, *args, **kw):
            mean = np.array(mean, dtype=float)
            mean[0, :2] += offset
            super().__init__(tracks, mean, cov, t0, *args, recover_after=self.recover_after, **kw)

    original = replay_mod.TeamEKF
    try:
        replay_mod.TeamEKF = Kidnapped
        for recover_after in (3, None):
            Kidnapped.recover_after = recover_after
            for est in ("ekf", "ekf_team"):
                r = replay_mod.replay(data, est, params, duration=duration)
                d = r.estimate[..., :2] - r.truth[..., :2]
                err = np.where(r.valid, np.hypot(d[..., 0], d[..., 1]), np.nan)
                close = np.nonzero(err[0] < 0.5)[0]
                out[f"{est} recover_after={recover_after}"] = {
                    "robot1_mean_error_m": float(np.nanmean(err[0])),
                    "team_mean_error_m": float(np.nanmean(err)),
                    "robot1_seconds_to_0.5m": float(r.times[close[0]] - r.times[0])
                    if len(close) else None,
                    "rejected": r.rejected.tolist(),
                }
    finally:
        replay_mod.TeamEKF = original
    return out


PROBES = {"forward": forward, "half_gps": half_gps, "wall": wall, "kidnapped_log": kidnapped_log}


def main(argv: list[str] | None = None) -> int:
    parser = ScriptParser(description=__doc__.splitlines()[0])
    parser.add_argument("--probe", nargs="+", default=["forward", "half_gps", "wall"],
                        choices=list(PROBES))
    parser.add_argument("--mrclam", default=None, help="MR.CLAM dataset folder (kidnapped_log)")
    parser.add_argument("--json", default=None, help="also write the figures to this file")
    args = parser.parse_args(argv)
    if "kidnapped_log" in args.probe and args.mrclam is None:
        print("--probe kidnapped_log needs --mrclam DATASET", file=sys.stderr)
        return 2
    out = {}
    for name in args.probe:
        out[name] = PROBES[name](args.mrclam) if name == "kidnapped_log" else PROBES[name]()
        print(name, json.dumps(out[name]), flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(run_script(main))
