"""Shared test configuration."""

import os

# One BLAS thread: the suite runs on 2 cores and small solves only lose from threading.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import matplotlib  # noqa: E402

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.pop("DISPLAY", None)
matplotlib.use("Agg")


import importlib.util  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _load_script(name: str):
    """The module of ``scripts/<name>.py``, freshly loaded."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def script_module():
    """Load ``scripts/<name>.py`` and return the module."""
    return _load_script


@pytest.fixture
def script_main():
    """Load ``scripts/<name>.py`` and return its ``main`` function."""
    return lambda name: _load_script(name).main


# Tests that take more than ~3 s each (``pytest --durations=0`` on the 2-core development
# machine under load), marked ``slow`` here in one place: ``pytest -m "not slow"`` is the
# quick check, the full suite runs them all. An entry without ``[...]`` covers every
# parameter of the test.
SLOW_TESTS = frozenset({
    "test_bench_vector_env.py::test_every_side_steps_its_worlds",
    "test_missing_extras.py::test_every_script_names_the_extra_of_a_missing_package",
    "test_benchmarl.py::test_the_one_line_command_runs_with_the_short_preset",
    "test_torch_threads.py::test_the_torchrl_and_benchmarl_entry_points_set_it",
    "test_benchmarl.py::test_a_tiny_mappo_run_on_rendezvous",
    "test_camera_pipeline.py::test_teams_without_cameras_read_nothing",
    "test_compare.py::test_evaluate_compare_prints_one_table_and_saves_plot_and_json",
    "test_compare.py::test_still_policy_covers_less_than_random",
    "test_density_tree.py::test_monte_carlo_integral_of_pdf_over_the_domain_is_one",
    "test_doc_blocks.py::test_page_blocks_run",
    "test_ekf.py::test_filter_is_consistent_with_gps_over_a_long_run",
    "test_env_api.py::test_aec_api[dispersal]",
    "test_env_api.py::test_aec_api[hexagon]",
    "test_env_api.py::test_aec_api[symmetric_hallway]",
    "test_env_api.py::test_aec_seed[circuit]",
    "test_env_api.py::test_aec_seed[dispersal]",
    "test_env_api.py::test_aec_seed[hexagon]",
    "test_env_api.py::test_aec_seed[symmetric_hallway]",
    "test_env_api.py::test_parallel_api[dispersal]",
    "test_env_api.py::test_parallel_api[hexagon]",
    "test_env_api.py::test_parallel_api[symmetric_hallway]",
    "test_env_api.py::test_parallel_seed[dispersal]",
    "test_env_api.py::test_parallel_seed[hexagon]",
    "test_env_api.py::test_parallel_seed[symmetric_hallway]",
    "test_env_api.py::test_render",
    "test_env_behaviour.py::test_full_episode_is_deterministic[dispersal]",
    "test_env_behaviour.py::test_full_episode_is_deterministic[hexagon]",
    "test_env_behaviour.py::test_full_episode_is_deterministic[symmetric_hallway]",
    "test_evaluate.py::test_evaluate_writes_valid_json_and_plots",
    "test_evaluate.py::test_render_episode_saves_gif",
    "test_evaluate.py::test_saved_sb3_model_is_a_policy",
    "test_examples.py::test_train_example",
    "test_fox.py::test_detections_shorten_the_time_to_localize_in_the_hallway",
    "test_fox.py::test_reproduce_fox_script_writes_json",
    "test_fox.py::test_wander_reads_each_robots_own_scan",
    "test_fsm.py::test_fsm_long_run_visits_every_state_safely",
    "test_howard.py::test_circuit_error_drops_at_each_sighting_and_at_loop_closure",
    "test_howard.py::test_dispersal_error_lowest_while_crowded",
    "test_howard.py::test_script_writes_json",
    "test_imitation.py::test_cloning_fits_the_teacher_and_the_returns",
    "test_madhavan.py::test_script_writes_json",
    "test_mcl_env.py::test_cooperative_updates_switch_transfers",
    "test_mcl_env.py::test_kidnapped_robot_is_recovered_on_the_envs_resampling_schedule",
    "test_mcl_env.py::test_episode_is_deterministic_with_mcl[dispersal]",
    "test_mcl_env.py::test_parallel_api_with_mcl[dispersal]",
    "test_mle_env.py::test_episode_is_deterministic_with_mle[dispersal]",
    "test_mle_env.py::test_episode_is_deterministic_with_mle[hexagon]",
    "test_mle_env.py::test_episode_is_deterministic_with_mle[symmetric_hallway]",
    "test_mle_env.py::test_parallel_api_with_mle[dispersal]",
    "test_mle_env.py::test_prior_anchors_the_global_frame",
    "test_mle_online.py::test_covariance_is_consistent_with_errors",
    "test_mle_online.py::test_gate_rejects_false_detections",
    "test_mle_online.py::test_observations_beat_odometry_alone",
    "test_mle_online.py::test_priors_alone_fix_the_frame_without_anchor",
    "test_mle_online.py::test_sliding_window_stays_close_to_full_batch",
    "test_mle_online.py::test_window_bounds_graph_size_on_long_runs",
    "test_mrclam.py::test_cli_writes_the_documented_json",
    "test_mrclam.py::test_mle_runs_on_excerpt_and_beats_dead_reckoning",
    "test_particle_filter.py::test_beam_model_tracks_with_wide_cones[180]",
    "test_quoted_commands.py::test_belief_honesty_figures_quoted_in_the_docs",
    "test_rllib.py::test_tiny_training_then_evaluate_and_compare",
    "test_sb3_adapter.py::test_two_processes_match_one_process",
    "test_sb3_batched.py::test_dict_observations_flatten_per_entry",
    "test_sb3_batched.py::test_training_on_the_batched_env_learns_the_model_the_copies_learn",
    "test_symmetric_copies.py::test_a_certified_robot_checked_again_keeps_what_it_saw",
    "test_torchrl.py::test_torchrl_env_specs_and_rollout_on_every_scenario",
    "test_training.py::test_tiny_training_saves_a_model_that_evaluate_loads",
    "test_torchrl.py::test_wrapper_with_default_arguments_on_every_scenario",
    "test_vector_env.py::test_every_estimator_and_obs_format_replays_parallel_env[mcl-dict]",
    "test_vector_env.py::test_every_scenario_replays_parallel_env[active_hallway]",
    "test_vector_env.py::test_every_scenario_replays_parallel_env[hexagon]",
    # active_lattice draws a new map (its MCL tables) at every reset
    "test_belief_map.py::test_parallel_api_with_dict_observation[active_lattice]",
    "test_truth_leaks.py::test_observation_never_reads_the_true_poses[active_lattice-ekf]",
    "test_truth_leaks.py::test_observation_never_reads_the_true_poses[active_lattice-mcl]",
    "test_truth_leaks.py::test_observation_never_reads_the_true_poses[active_lattice-mle]",
    "test_torchrl.py::test_torchrl_env_specs_and_rollout_on_every_scenario[active_lattice]",
    "test_env_behaviour.py::test_full_episode_is_deterministic[active_lattice]",
    "test_env_api.py::test_aec_api[active_lattice]",
    "test_env_api.py::test_aec_seed[active_lattice]",
    "test_env_api.py::test_parallel_api[active_lattice]",
    "test_env_api.py::test_parallel_seed[active_lattice]",
    "test_env_api.py::test_max_cycles[active_lattice]",
    "test_mle_env.py::test_parallel_api_with_mle[active_lattice]",
    "test_mle_env.py::test_episode_is_deterministic_with_mle[active_lattice]",
    "test_mcl_env.py::test_episode_is_deterministic_with_mcl[active_lattice]",
    "test_mcl_env.py::test_parallel_api_with_mcl[active_lattice]",
    "test_active_lattice.py::test_one_observation_shape_for_every_size",
    "test_active_lattice.py::test_new_map_every_episode_unless_map_seed_is_set",
    "test_range_cast.py::test_compiled_table_equals_the_vectorized_one",
    "test_lattice_policies.py::test_baselines_never_read_the_truth",
    "test_lattice_policies.py::test_split_sends_the_team_to_different_places",
})


def pytest_collection_modifyitems(config, items):
    """Mark the tests of :data:`SLOW_TESTS` ``slow``."""
    for item in items:
        path, _, name = item.nodeid.partition("::")  # tests/<package>/test_x.py::name
        nodeid = f"{path.rsplit('/', 1)[-1]}::{name}"
        if nodeid in SLOW_TESTS or nodeid.split("[")[0] in SLOW_TESTS:
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def steep_and_flat():
    """Start poses ``(on a steep patch, far from it on flat ground)`` of ``outdoor_terrain``:
    a robot started on the first tips over at its first step, one on the second does not."""
    import numpy as np

    import coop_loc_env

    terrain = coop_loc_env.parallel_env("outdoor_terrain").world.terrain
    cx, cy = terrain.steep_centers[0]
    grid = np.stack(np.meshgrid(np.linspace(1, 39, 77), np.linspace(1, 39, 77)), -1).reshape(-1, 2)
    steep = grid[terrain.is_steep(grid)]
    flat = grid[~terrain.is_steep(grid)]
    s = steep[np.argmin(np.hypot(*(steep - (cx, cy)).T))]
    f = flat[np.argmax(np.hypot(*(flat - s).T))]
    return (float(s[0]), float(s[1]), 0.0), (float(f[0]), float(f[1]), 0.0)


@pytest.fixture(scope="session")
def mean_position_error():
    """``f(scenario, policy, seeds, **overrides) -> float``: the mean over episodes (one per
    seed) of the mean over steps and robots of the ``position_error`` infos of ``policy``,
    stepped here directly (what an evaluation should report as its localization error)."""
    import numpy as np

    import coop_loc_env

    def mean(scenario: str, policy, seeds, **overrides) -> float:
        overrides = {**(getattr(policy, "env_settings", None) or {}), **overrides}
        per_episode = []
        for seed in seeds:
            env = coop_loc_env.parallel_env(scenario, **overrides)
            obs, _ = env.reset(seed=seed)
            policy.reset(env, seed=seed)
            errors = []
            while env.agents:
                obs, _, _, _, infos = env.step(policy.act(obs))
                errors.extend(info["position_error"] for info in infos.values())
            per_episode.append(np.mean(errors))
        return float(np.mean(per_episode))

    return mean


@pytest.fixture(scope="session")
def actions_with_shifted_truth():
    """``f(env, policy, obs, rng, shift=5.0) -> (before, after)``: the actions of copies of
    ``policy`` on ``obs``, before and after the true poses are shifted by up to ``shift`` m
    and 1 rad (then restored). A policy that never reads the truth gives equal ones."""
    import copy

    def actions(env, policy, obs, rng, shift: float = 5.0):
        before = copy.deepcopy(policy, memo={id(env): env}).act(obs)
        saved = env.world.poses.copy()
        n = env.config.n_robots
        env.world.poses[:, :2] += rng.uniform(-shift, shift, size=(n, 2))
        env.world.poses[:, 2] += rng.uniform(-1.0, 1.0, size=n)
        after = copy.deepcopy(policy, memo={id(env): env}).act(obs)
        env.world.poses[:] = saved
        return before, after

    return actions
