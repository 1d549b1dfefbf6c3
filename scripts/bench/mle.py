"""Benchmark of the team-MLE estimator: batch solve and online per-step cost.

``bench_mle()`` returns a flat ``dict[str, float]`` (``scripts/benchmark.py``
prints it); run this file to print it standalone::

    python scripts/bench/mle.py [--quick]

* **batch**: a random dispersal graph of 20 robots x 30 sampled times
  (:func:`estimators.pose_graph.random_team_graph`: each ordered pair within 8 m
  observed with probability 0.5 per sampled time, Howard et al.'s 5 % range
  noise) solved from dead reckoning by our Levenberg-Marquardt. If the optional
  ``gtsam`` package is importable, the same graph (``BetweenFactorPose2`` for
  motion, ``BearingRangeFactorPose2`` plus an orientation-only
  ``BetweenFactorPose2`` for robot observations, a tight prior as the anchor) is
  solved by GTSAM's Levenberg-Marquardt from the same start, and the time ratios
  (wall clock and CPU) and both final costs are reported. Timings are best of
  ``repeats``; on a loaded machine prefer the CPU figures, and set
  ``OPENBLAS_NUM_THREADS=1`` (threaded BLAS on small matrices under load is slow).
* **howard_circuit**: the whole pose graph of the ``circuit`` reproduction
  (``--profile paper``: every robot observation on nodes at its own time, no
  gate; 175 s, seed 0; recorded with ``extras["mle_keep_history"]``, the same
  factors as the whole-graph run) solved from dead reckoning by our
  Levenberg-Marquardt and, if ``gtsam`` is installed, by GTSAM's
  (:mod:`estimators.gtsam_bridge`): both final costs, their relative
  difference and the time ratios (best of ``repeats``).
* **online**: :class:`estimators.mle_online.TeamMLE` fed a simulated 20-robot
  stream at 10 Hz (odometry every step, robot observations within 6 m); the
  per-step wall time (add data + ``step`` + ``poses`` + ``covariances``) is
  reported for the first and last third of the run to show that it is bounded.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from coop_loc_env.cli import ScriptParser, run_script
from estimators.gtsam_bridge import dead_reckoning
from estimators.mle_online import TeamMLE, simulate_team_stream
from estimators.pose_graph import PairSensing, PoseGraph, optimize, random_team_graph
from estimators.relative_metrics import relative_errors


def _gtsam_solve(graph: PoseGraph, start: np.ndarray) -> tuple[float, float, float, int] | None:
    """Solve ``graph`` from ``start`` with GTSAM LM: ``(wall s, CPU s, final cost, iterations)``."""
    try:
        import gtsam  # optional, benchmark only
    except ImportError:
        return None
    fg = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for n in range(graph.n_nodes):
        values.insert(n, gtsam.Pose2(*start[n]))
    for n in np.flatnonzero(graph.fixed):
        fg.add(gtsam.PriorFactorPose2(int(n), gtsam.Pose2(*start[n]),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 1e-9)))
    tables = graph.factor_tables()
    for (i, j), mu, w in zip(*tables["between"], strict=True):
        fg.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*mu),
                                        gtsam.noiseModel.Gaussian.SqrtInformation(w)))
    for (a, b), mu, w, off in zip(*tables["observation"], strict=True):
        if np.any(off) or np.count_nonzero(w - np.diag(np.diag(w))) or np.any(np.diag(w) == 0):
            raise ValueError("the GTSAM comparison needs diagonal range/bearing/orientation noise")
        sig = 1.0 / np.diag(w)
        fg.add(gtsam.BearingRangeFactorPose2(int(a), int(b), gtsam.Rot2(mu[1]), mu[0],
                                             gtsam.noiseModel.Diagonal.Sigmas(sig[[1, 0]])))
        orient_only = gtsam.noiseModel.Diagonal.Precisions(np.array([0.0, 0.0, w[2, 2] ** 2]))
        fg.add(gtsam.BetweenFactorPose2(int(a), int(b), gtsam.Pose2(0.0, 0.0, mu[2]),
                                        orient_only))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(100)
    t0, c0 = time.perf_counter(), time.process_time()
    optimizer = gtsam.LevenbergMarquardtOptimizer(fg, values, params)
    result = optimizer.optimize()
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    return seconds, cpu, float(fg.error(result)), int(optimizer.iterations())


def bench_batch(n_robots: int = 20, n_times: int = 30, repeats: int = 3, seed: int = 2) -> dict:
    """Batch solve time (best of ``repeats``) and final cost; GTSAM's if installed."""
    out: dict[str, float] = {}
    team = random_team_graph(n_robots, n_times, np.random.default_rng(seed), room=6.0)
    start = team.graph.poses.copy()
    best = best_cpu = np.inf
    for _ in range(repeats):
        team.graph.poses[:] = start
        t0, c0 = time.perf_counter(), time.process_time()
        res = optimize(team.graph)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    dof = res.n_residuals - res.n_variables
    out.update(
        {
            "mle_batch_nodes": float(team.graph.n_nodes),
            "mle_batch_robot_observations": float(team.graph.n_observations),
            "mle_batch_time_s": best,
            "mle_batch_cpu_s": best_cpu,
            "mle_batch_iterations": float(res.iterations),
            "mle_batch_final_cost": res.cost,
            "mle_batch_cost_chi2_z": (2 * res.cost - dof) / np.sqrt(2 * dof),
        }
    )
    gt_best = gt_cpu = np.inf
    gt = None
    for _ in range(repeats):
        gt = _gtsam_solve(team.graph, start)
        if gt is None:
            break
        gt_best, gt_cpu = min(gt_best, gt[0]), min(gt_cpu, gt[1])
    if gt is not None:
        out.update(
            {
                "gtsam_batch_time_s": gt_best,
                "gtsam_batch_cpu_s": gt_cpu,
                "gtsam_batch_iterations": float(gt[3]),
                "gtsam_batch_final_cost": gt[2],
                "mle_over_gtsam_time_ratio": best / gt_best,
                "mle_over_gtsam_cpu_ratio": best_cpu / gt_cpu,
                "mle_gtsam_cost_rel_diff": abs(res.cost - gt[2]) / max(abs(gt[2]), 1e-300),
            }
        )
    return out


def howard_circuit_graph(duration_s: float = 175.0, seed: int = 0) -> PoseGraph:
    """The whole pose graph of the paper-profile ``circuit`` run (every factor, no window)."""
    import coop_loc_env
    from coop_loc_env.backends.mle import MLEBackend
    from coop_loc_env.profiles import with_profile
    from policies.scripted.circuit import CircuitPolicy

    overrides = with_profile("circuit", "paper")
    # A short window while recording: the same factors, far cheaper than re-solving them all.
    overrides["extras"] = {**overrides["extras"], "mle_window": 5, "mle_keep_history": True}
    env = coop_loc_env.parallel_env("circuit", **overrides)
    obs, _ = env.reset(seed=seed)
    policy = CircuitPolicy()
    policy.reset(env, seed)
    for _ in range(int(round(duration_s / env.config.dt))):
        obs, *_ = env.step(policy.act(obs))
    graph = next(b for b in env.backends if isinstance(b, MLEBackend)).mle.history
    env.close()
    return graph


def bench_howard_circuit(repeats: int = 3) -> dict[str, float]:
    """Our batch solve vs GTSAM's on the circuit reproduction's whole graph."""
    graph = howard_circuit_graph()
    start = dead_reckoning(graph)
    best = best_cpu = np.inf
    for _ in range(repeats):
        graph.poses[:] = start
        t0, c0 = time.perf_counter(), time.process_time()
        res = optimize(graph, max_iterations=100)
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    out = {
        "howard_circuit_nodes": float(graph.n_nodes),
        "howard_circuit_robot_observations": float(graph.n_observations),
        "howard_circuit_time_s": best,
        "howard_circuit_cpu_s": best_cpu,
        "howard_circuit_iterations": float(res.iterations),
        "howard_circuit_final_cost": res.cost,
    }
    try:
        from estimators.gtsam_bridge import gtsam_solve

        gt = [gtsam_solve(graph, start) for _ in range(repeats)]
    except ImportError:
        return out
    gt_best = min(g.seconds for g in gt)
    gt_cpu = min(g.cpu_seconds for g in gt)
    out.update({
        "howard_circuit_gtsam_time_s": gt_best,
        "howard_circuit_gtsam_cpu_s": gt_cpu,
        "howard_circuit_gtsam_iterations": float(gt[0].iterations),
        "howard_circuit_gtsam_final_cost": gt[0].cost,
        "howard_circuit_cost_rel_diff": abs(res.cost - gt[0].cost) / abs(gt[0].cost),
        "howard_circuit_mle_over_gtsam_time_ratio": best / gt_best,
        "howard_circuit_mle_over_gtsam_cpu_ratio": best_cpu / gt_cpu,
    })
    return out


def bench_online(n_robots: int = 20, n_steps: int = 1500, seed: int = 0) -> dict:
    """Per-step cost of :class:`TeamMLE` on a simulated dispersal stream (10 Hz)."""
    stream = simulate_team_stream(
        n_robots, n_steps, np.random.default_rng(seed), room=8.0,
        sensing=PairSensing(sensor_range=6.0, p_observe=0.2),
    )
    est = TeamMLE(n_robots, initial_poses=stream.truth[0], initial_std=[0.5, 0.5, 0.2],
                  motion_window=10.0, window=10)
    times = np.zeros(n_steps)
    nodes = np.zeros(n_steps)
    for k in range(n_steps):
        t0 = time.perf_counter()
        for r in range(n_robots):
            est.add_odometry(r, *stream.odometry[k, r], stream.dt)
        for a, b, meas, std in stream.observations[k]:
            est.add_observation(a, b, meas, std)
        est.step()
        est.poses()
        est.covariances()
        times[k] = time.perf_counter() - t0
        nodes[k] = est.n_active_nodes
    third = n_steps // 3
    err = relative_errors(est.poses(), stream.truth[-1])
    return {
        "mle_online_robots": float(n_robots),
        "mle_online_steps": float(n_steps),
        "mle_online_step_ms_mean": 1e3 * float(times.mean()),
        "mle_online_step_ms_first_third": 1e3 * float(times[:third].mean()),
        "mle_online_step_ms_last_third": 1e3 * float(times[-third:].mean()),
        "mle_online_step_ms_p99": 1e3 * float(np.percentile(times, 99)),
        "mle_online_max_active_nodes": float(nodes.max()),
        "mle_online_final_relative_range_error_m": float(err[0]),
    }


def bench_mle(quick: bool = False) -> dict[str, float]:
    """All team-MLE figures: batch and Howard circuit (and GTSAM if installed), online cost."""
    out = bench_batch(repeats=1 if quick else 3)
    out.update(bench_howard_circuit(repeats=1 if quick else 3))
    out.update(bench_online(n_steps=300 if quick else 1500))
    return out


def main() -> None:
    parser = ScriptParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, shorter online run")
    args = parser.parse_args()
    for key, value in bench_mle(quick=args.quick).items():
        print(f"{key:45s} {value:.6g}")


if __name__ == "__main__":
    sys.exit(run_script(main))
