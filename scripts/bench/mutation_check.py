"""Mutation check: does the fast test suite notice when one constant or line changes?

Each mutation of :data:`MUTATIONS` replaces one exact piece of text of one file (a
default, a threshold, a sign) in a scratch copy of the repository (the working tree
is never touched), runs its targeted tests of the fast suite (``-m "not slow"``) there
with ``PYTHONPATH`` set to the copy, and restores the file. A mutation is *caught*
when a test fails, *survived* when they all pass; the first failing test is named.
Before the mutations, the same tests run once on the unchanged copy (the baseline):
a test that fails there would "catch" everything.

    python scripts/bench/mutation_check.py                 # every mutation, a few minutes
    python scripts/bench/mutation_check.py --list          # names, files and tests
    python scripts/bench/mutation_check.py --only gps_multipath_prob --json out.json

To add a mutation, append a :class:`Mutation` to :data:`MUTATIONS`: its ``original``
must occur exactly once in its file (a mutation whose text is gone is reported as an
error, not as caught), and its tests should be the few fast ones meant to catch it.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

ROOT = Path(__file__).resolve().parents[2]
# Never copied into the scratch tree (when the root is not a git checkout).
IGNORED = (".git", ".venv", "__pycache__", ".pytest_cache", ".ruff_cache", "*.egg-info",
           "outputs", "runs")


class Mutation(NamedTuple):
    """Replace ``original`` (exactly one occurrence) in ``path`` by ``replacement``, then
    run ``tests`` (pytest node ids or paths, relative to the repository root)."""

    name: str
    path: str
    original: str
    replacement: str
    tests: tuple[str, ...]


class Outcome(NamedTuple):
    """What one mutation gave: ``caught``, ``survived``, ``timeout`` or ``error``."""

    name: str
    result: str
    caught_by: str = ""
    detail: str = ""
    seconds: float = 0.0


MCL_TESTS = "tests/estimators/mcl/"
GPS_TEST = "tests/env/test_observation_gps.py::test_multipath_fixes_are_two_percent"
GOLDEN = "tests/env/test_golden_rollouts.py"
M = Mutation
MUTATIONS: tuple[Mutation, ...] = (
    M("mcl_default_n_particles", "estimators/mcl/config.py",
      "n_particles: int = 1000", "n_particles: int = 1100",
      (MCL_TESTS + "test_particle_filter.py::test_default_filter_spreads_1000_particles",)),
    M("min_bayes_factor", "estimators/mcl/detection_consistency.py",
      "min_bayes_factor: float = 0.1", "min_bayes_factor: float = 0.2",
      (MCL_TESTS + "test_detection_consistency.py::test_default_bayes_factor_threshold",)),
    M("confident_mass", "estimators/mcl/detection_consistency.py",
      "confident_mass: float = 0.6", "confident_mass: float = 0.7",
      (MCL_TESTS + "test_detection_consistency.py::test_default_confident_mass",)),
    M("agree_prob", "estimators/gating.py",
      "AGREE_PROB = 0.999", "AGREE_PROB = 0.99",
      ("tests/env/test_belief_recovery.py::test_rejections_agree_up_to_the_0999_quantile",)),
    M("gps_multipath_prob", "coop_loc_env/config.py",
      "gps_multipath_prob: float = _probability(0.02)",
      "gps_multipath_prob: float = _probability(0.03)",
      (GPS_TEST,)),
    M("hypothesis_cost_weight", "policies/scripted/hypothesis.py",
      "cost_weight: float = 0.01", "cost_weight: float = 0.02",
      ("tests/policies/test_planner_decisions.py",)),
    M("relocalizer_min_ratio", "estimators/relocalization.py",
      "min_ratio: float = 4.0,", "min_ratio: float = 3.0,",
      ("tests/estimators/test_lockout_recovery.py::test_consensus_needs_four_times_the_fit",)),
    M("replay_measurement_delay_sign", "estimators/replay/runner.py",
      "t = m[:, 0] - params.measurement_delay_s", "t = m[:, 0] + params.measurement_delay_s",
      ("tests/estimators/test_mrclam_reference.py",)),
    M("resample_ess_fraction", "estimators/mcl/config.py",
      "resample_ess_fraction: float = 0.5", "resample_ess_fraction: float = 0.55",
      (MCL_TESTS + "test_particle_filter.py::test_resampling_starts_below_half_the_particles",)),
    M("motion_floor_std", "estimators/mle_online.py",
      "motion_floor_std: tuple[float, float] = (1e-3, 1e-3)",
      "motion_floor_std: tuple[float, float] = (1.1e-3, 1.1e-3)",
      ("tests/estimators/test_mle_online.py::test_motion_floor_is_the_variance_of_a_still_robot",)),
    M("chi2_threshold", "estimators/gating.py",
      "_CHI2_CACHE[key] = float(chi2.ppf(prob, dof))",
      "_CHI2_CACHE[key] = float(1.1 * chi2.ppf(prob, dof))",
      ("tests/estimators/test_ekf.py::test_gate_decides_at_the_chi2_quantile",
       "tests/estimators/test_ekf.py::test_gate_rejects_injected_outliers_and_accepts_inliers")),
    M("active_hallway_n_particles", "coop_loc_env/scenarios/active_hallway.py",
      "n_particles=1000,", "n_particles=1100,",
      ("tests/policies/test_active_hallway.py::test_active_hallway_starts_4000_particles_a_robot",)),
    # --- beyond the list above: noise constants, reward weights, gates
    M("env_default_n_particles", "coop_loc_env/config.py",
      "n_particles: int = 1000", "n_particles: int = 1100",
      ("tests/env/test_mcl_env.py::test_default_particle_count_is_1000",)),
    M("gps_std", "coop_loc_env/config.py",
      "gps_std: float = _non_negative(0.3)", "gps_std: float = _non_negative(0.33)",
      (GPS_TEST,)),
    M("gps_multipath_std", "coop_loc_env/config.py",
      "gps_multipath_std: float = _non_negative(5.0)",
      "gps_multipath_std: float = _non_negative(5.5)",
      (GPS_TEST,)),
    M("odom_v_std", "coop_loc_env/config.py",
      "odom_v_std: float = _non_negative(0.05)", "odom_v_std: float = _non_negative(0.055)",
      (GOLDEN,)),
    M("detection_prob", "coop_loc_env/config.py",
      "detection_prob: float = _probability(0.933)", "detection_prob: float = _probability(0.9)",
      (GOLDEN,)),
    M("env_gate_prob", "coop_loc_env/config.py",
      "gate_prob: float = 0.99", "gate_prob: float = 0.995",
      ("tests/env/test_observation_gps.py::test_env_filters_gate_fixes_at_the_99_percent_"
       "quantile",)),
    M("reward_localization_weight", "coop_loc_env/config.py",
      "reward_localization_weight: float = _non_negative(1.0)",
      "reward_localization_weight: float = _non_negative(1.1)",
      ("tests/env/test_env_behaviour.py",)),
    M("mode_radius", "estimators/mcl/detection_consistency.py",
      "mode_radius: float = 2.0", "mode_radius: float = 2.2",
      (MCL_TESTS + "test_detection_consistency.py::test_default_mode_radius",)),
    M("move_fraction", "estimators/mcl/detection_consistency.py",
      "move_fraction: float = 0.5", "move_fraction: float = 0.55",
      (MCL_TESTS + "test_detection_consistency.py::test_default_move_fraction",)),
    M("mcl_lf_sigma", "estimators/mcl/config.py",
      "lf_sigma: float = 0.2", "lf_sigma: float = 0.22",
      (MCL_TESTS + "test_particle_filter.py", MCL_TESTS + "test_likelihood_field.py")),
    M("mcl_random_fraction", "estimators/mcl/config.py",
      "random_fraction: float = 0.03", "random_fraction: float = 0.033",
      (MCL_TESTS + "test_particle_filter.py::test_resampling_injects_three_percent_uniform_"
       "particles",)),
    M("mcl_global_init_factor", "coop_loc_env/backends/mcl.py",
      "GLOBAL_INIT_FACTOR = 4 ", "GLOBAL_INIT_FACTOR = 5 ",
      ("tests/policies/test_active_hallway.py",)),
    M("ekf_recover_after", "estimators/ekf.py",
      "recover_after: int | None = 3,", "recover_after: int | None = 4,",
      ("tests/env/test_belief_recovery.py",)),
    M("relocalizer_min_jump", "estimators/relocalization.py",
      "min_jump: float = 1.5,", "min_jump: float = 1.65,",
      ("tests/estimators/test_lockout_recovery.py",)),
    M("gate_run_not_reset_by_acceptance", "estimators/gating.py",
      "c = np.where(accepted, 0, prev + 1)", "c = np.where(accepted, prev, prev + 1)",
      ("tests/env/test_belief_recovery.py",)),
)


def _scratch_files(root: Path) -> list[str] | None:
    """The files of ``root`` git tracks or would track (``None`` outside a git checkout)."""
    try:
        out = subprocess.run(["git", "-C", str(root), "ls-files", "-co", "--exclude-standard",
                              "-z"], capture_output=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return [f for f in out.stdout.decode().split("\0") if f]


def make_scratch(root: Path, into: Path) -> Path:
    """Copy ``root``'s source tree (git's view of it when it is a checkout) under ``into``."""
    dest = into / "repo"
    files = _scratch_files(root)
    if files is None:
        shutil.copytree(root, dest, ignore=shutil.ignore_patterns(*IGNORED))
        return dest
    for rel in files:
        src = root / rel
        if src.is_file():  # a deleted but still tracked file is skipped
            target = dest / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, target)
    return dest


def _pytest(scratch: Path, tests: tuple[str, ...], timeout: float) -> tuple[int | None, str]:
    """Run ``tests`` in ``scratch`` (fast suite, first failure stops); (exit code, output).
    The exit code is ``None`` on a timeout."""
    env = dict(os.environ, PYTHONPATH=str(scratch), PYTHONDONTWRITEBYTECODE="1")
    cmd = [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-m",
           "not slow", "-rf", "--no-header", *tests]
    try:
        proc = subprocess.run(cmd, cwd=scratch, env=env, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, ""
    return proc.returncode, proc.stdout + proc.stderr


def _first_failure(output: str) -> str:
    match = re.search(r"^(?:FAILED|ERROR) (\S+)", output, re.MULTILINE)
    return match.group(1) if match else ""


def apply(mutation: Mutation, scratch: Path) -> str:
    """Write ``mutation`` into ``scratch``; returns the original text of the file."""
    path = scratch / mutation.path
    if not path.is_file():
        raise ValueError(f"{mutation.path} does not exist")
    text = path.read_text()
    count = text.count(mutation.original)
    if count != 1:
        raise ValueError(f"{mutation.original!r} occurs {count} times in {mutation.path}, "
                         f"not once")
    path.write_text(text.replace(mutation.original, mutation.replacement))
    return text


def run_one(mutation: Mutation, root: Path, scratch: Path, timeout: float) -> Outcome:
    """Apply ``mutation`` in ``scratch``, run its tests there, restore the file."""
    start = time.perf_counter()
    try:
        apply(mutation, scratch)
    except ValueError as err:
        return Outcome(mutation.name, "error", detail=str(err))
    try:
        code, output = _pytest(scratch, mutation.tests, timeout)
    finally:  # the copy's own file back, with its time stamp (byte-compiled caches match)
        shutil.copy2(root / mutation.path, scratch / mutation.path)
    seconds = time.perf_counter() - start
    if code is None:
        return Outcome(mutation.name, "timeout", detail=f"over {timeout:g} s", seconds=seconds)
    if code == 0:
        return Outcome(mutation.name, "survived", seconds=seconds)
    if code == 1:
        return Outcome(mutation.name, "caught", _first_failure(output), seconds=seconds)
    last = output.strip().splitlines()[-1] if output.strip() else ""
    return Outcome(mutation.name, "error", detail=f"pytest exit {code}: {last}", seconds=seconds)


def baseline(mutations: list[Mutation], scratch: Path, timeout: float) -> str | None:
    """``None`` when every targeted test passes on the unchanged copy, else why not."""
    tests = tuple(dict.fromkeys(t for m in mutations for t in m.tests))
    code, output = _pytest(scratch, tests, timeout)
    if code == 0:
        return None
    if code is None:
        return f"the unchanged tests ran over {timeout:g} s"
    failed = _first_failure(output) or output[-300:]
    return f"the unchanged tests fail (pytest exit {code}): {failed}"


def check(mutations: list[Mutation], root: Path = ROOT, timeout: float = 300.0,
          with_baseline: bool = True, echo=print) -> list[Outcome]:
    """Run ``mutations`` in one scratch copy of ``root``; one line per mutation to ``echo``."""
    with tempfile.TemporaryDirectory(prefix="mutation-check-") as tmp:
        scratch = make_scratch(root, Path(tmp))
        if with_baseline:
            problem = baseline(mutations, scratch, timeout)
            if problem is not None:
                raise RuntimeError(problem)
        outcomes = []
        width = max(len(m.name) for m in mutations)
        for mutation in mutations:
            outcome = run_one(mutation, root, scratch, timeout)
            outcomes.append(outcome)
            echo(f"{outcome.name:<{width}}  {outcome.result:<8}  {outcome.seconds:5.1f} s  "
                 f"{outcome.caught_by or outcome.detail}")
    return outcomes


def summary(outcomes: list[Outcome]) -> str:
    counts = {r: sum(o.result == r for o in outcomes)
              for r in ("caught", "survived", "timeout", "error")}
    return (f"{len(outcomes)} mutations: {counts['caught']} caught, {counts['survived']} "
            f"survived, {counts['timeout']} timed out, {counts['error']} errors")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", action="append", default=[], metavar="NAME",
                   help="run this mutation only (repeat or separate names by commas)")
    p.add_argument("--list", action="store_true", help="print the mutations and exit")
    p.add_argument("--json", metavar="FILE", help="also write the outcomes to FILE")
    p.add_argument("--timeout", type=float, default=300.0,
                   help="seconds per test run (default 300)")
    p.add_argument("--no-baseline", action="store_true",
                   help="skip the run of the targeted tests on the unchanged copy")
    p.add_argument("--root", type=Path, default=ROOT, help=argparse.SUPPRESS)
    return p


class _ArgumentError(Exception):
    pass


def _select(only: list[str]) -> list[Mutation]:
    names = [n for item in only for n in item.split(",") if n]
    known = {m.name: m for m in MUTATIONS}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise _ArgumentError(f"unknown mutation {unknown[0]!r}; --list shows the names")
    return [known[n] for n in names] if names else list(MUTATIONS)


def main(argv: list[str] | None = None, mutations: tuple[Mutation, ...] | None = None) -> int:
    parser = _parser()
    parser.error = lambda message: (_ for _ in ()).throw(_ArgumentError(message))
    try:
        args = parser.parse_args(argv)
        if not args.timeout > 0:
            raise _ArgumentError(f"--timeout must be > 0, got {args.timeout}")
        chosen = list(mutations) if mutations is not None else _select(args.only)
        if not args.root.is_dir():
            raise _ArgumentError(f"--root {args.root} is not a directory")
    except _ArgumentError as err:
        print(f"mutation_check: {err}", file=sys.stderr)
        return 2
    if args.list:
        for m in chosen:
            print(f"{m.name}: {m.path}: {m.original!r} -> {m.replacement!r}; "
                  f"tests {' '.join(m.tests)}")
        return 0
    try:
        outcomes = check(chosen, args.root, args.timeout, not args.no_baseline)
    except RuntimeError as err:
        print(f"mutation_check: {err}", file=sys.stderr)
        return 2
    print(summary(outcomes))
    if args.json:
        rows = [{"name": o.name, "result": o.result, "caught_by": o.caught_by,
                 "detail": o.detail, "seconds": round(o.seconds, 1)} for o in outcomes]
        Path(args.json).write_text(json.dumps(
            {"summary": summary(outcomes), "mutations": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
