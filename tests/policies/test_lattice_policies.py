"""The baselines on ``active_lattice``: they read beliefs, the known map and the team's
estimates, never the truth; ``split`` spreads the team, ``hypothesis:nearest`` picks the
nearest telling place, the oracle reads the truth (a reference only)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

import coop_loc_env
from estimators.mcl.map_symmetry import MapSymmetry
from policies.learning.loader import make_policy
from policies.scripted.hypothesis import ASSIGN_M, HypothesisPolicy, _raise_copies
from policies.scripted.split import SPLIT_PENALTY, SplitPolicy

ROOT = Path(__file__).resolve().parents[2]
SMALL = {"n_particles": 300, "map_seed": 8, "max_cycles": 60}


def _oracle_module():
    spec = importlib.util.spec_from_file_location(
        "lattice_oracle", ROOT / "scripts" / "bench" / "lattice_oracle.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _changed(policy, actions_with_shifted_truth, steps: int = 32) -> set[str]:
    env = coop_loc_env.parallel_env("active_lattice", **SMALL)
    obs, _ = env.reset(seed=3)
    policy.reset(env, seed=3)
    rng = np.random.default_rng(2)
    changed: set[str] = set()
    for t in range(steps):
        if t % 4 == 3:
            before, after = actions_with_shifted_truth(env, policy, obs, rng)
            changed |= {a for a in env.agents if not np.array_equal(before[a], after[a])}
        obs, *_ = env.step(policy.act(obs))
    return changed


@pytest.mark.parametrize("spec", ["wander", "corridor", "hypothesis", "hypothesis:nearest",
                                  "split"])
def test_baselines_never_read_the_truth(spec, actions_with_shifted_truth):
    assert _changed(make_policy(spec), actions_with_shifted_truth) == set()


def test_oracle_reads_the_truth(actions_with_shifted_truth):
    oracle = _oracle_module().LatticeOraclePolicy(1.0)
    assert _changed(oracle, actions_with_shifted_truth, steps=12)


def test_oracle_drives_toward_the_bay():
    oracle = _oracle_module().LatticeOraclePolicy(1.0)
    env = coop_loc_env.parallel_env("active_lattice", **SMALL)
    obs, _ = env.reset(seed=1)
    oracle.reset(env, seed=1)
    plan = oracle.plan
    bay = int(plan.cell_of(env.lattice.bay))

    def path_to_bay():
        return plan.distances(bay)[0][plan.cell_of(env.world.poses[:, :2])]

    start = path_to_bay()
    for _ in range(30):
        obs, *_ = env.step(oracle.act(obs))
    assert (path_to_bay() < start - 5.0).all()  # every robot 5 m nearer by path in 15 s


def test_bad_oracle_input_exits_2(capsys):
    assert _oracle_module().main(["--episodes", "0"]) == 2
    assert _oracle_module().main(["--scenario", "active_hallway"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("error:") for line in err)


def test_registry_arguments():
    assert make_policy("hypothesis:nearest").select == "nearest"
    assert make_policy("hypothesis:nearest").copies and not make_policy("hypothesis").copies
    assert make_policy("hypothesis").select == "utility"
    assert isinstance(make_policy("split"), SplitPolicy)
    with pytest.raises(ValueError, match="hypothesis:far"):
        make_policy("hypothesis:far")
    with pytest.raises(ValueError, match="split"):
        make_policy("split:2")
    with pytest.raises(ValueError, match="select"):
        HypothesisPolicy(select="far")
    with pytest.raises(ValueError, match="copies"):
        HypothesisPolicy(copies=1)


def test_copies_of_the_main_mode_weigh_as_much():
    quarter = MapSymmetry(math.pi / 2, (10.0, 10.0), 0.9)
    # main mode at (15, 10) heading 0; its quarter-turn copy at (10, 15) heading pi/2
    m = np.array([[0.9, 15.0, 10.0, 1.0, 0.0, 0.3],
                  [0.02, 10.2, 15.1, 0.0, 1.0, 0.3],  # the copy, kept with little mass
                  [0.05, 3.0, 3.0, 1.0, 0.0, 0.3],  # elsewhere: unchanged but renormalized
                  [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    out, found = _raise_copies(m, (quarter,))
    assert found and len(out) == 3
    assert out[0, 0] == pytest.approx(out[1, 0]) and {round(out[0, 1]), round(out[1, 1])} == {
        15, 10}
    assert out[:, 0].sum() == pytest.approx(1.0)
    assert out[2, 0] == pytest.approx(0.05 / 1.85)
    # a mode turned the wrong way is no copy
    m[1, 3:5] = (0.0, -1.0)
    out, found = _raise_copies(m, (quarter,))
    assert not found and out[0, 0] == pytest.approx(0.9)


def test_split_avoids_every_teammates_current_place():
    env = coop_loc_env.parallel_env("active_lattice", **SMALL)
    env.reset(seed=0)
    policy = SplitPolicy()
    policy.reset(env, seed=0)
    lead, target = np.array([10.0, 10.0, 0.0]), np.array([14.0, 10.0])
    policy.state[1].lead, policy.state[1].target = lead, target
    assert any(np.array_equal(t, target) for _, t in policy._teammate_targets(0, []))
    assert not any(np.array_equal(t, target) for _, t in policy._teammate_targets(1, []))
    plain = HypothesisPolicy()
    plain.reset(env, seed=0)
    plain.state[1].lead, plain.state[1].target = lead, target
    assert plain._teammate_targets(0, []) == []  # hypothesis: only this step's choices
    assert SPLIT_PENALTY >= 1.0 and policy.assign_penalty == SPLIT_PENALTY


def test_split_sends_the_team_to_different_places():
    env = coop_loc_env.parallel_env("active_lattice", **{**SMALL, "max_cycles": 80})
    obs, _ = env.reset(seed=5)
    policy = SplitPolicy()
    policy.reset(env, seed=5)
    spread = 0.0
    for _ in range(60):
        obs, *_ = env.step(policy.act(obs))
        chosen = [(st.lead, st.target) for st in policy.state.values() if st.target is not None]
        for a in range(len(chosen)):
            for b in range(a + 1, len(chosen)):
                (la, ta), (lb, tb) = chosen[a], chosen[b]
                if np.hypot(*(la[:2] - lb[:2])) < env.config.detector_range:
                    spread = max(spread, float(np.hypot(*(ta - tb))))
    assert spread >= ASSIGN_M


def test_nearest_picks_a_nearer_place_than_utility():
    env = coop_loc_env.parallel_env("active_lattice", **SMALL)
    obs, _ = env.reset(seed=2)
    runner = HypothesisPolicy(select="nearest")
    runner.reset(env, seed=2)
    probe = HypothesisPolicy(copies=True)
    probe.reset(env, seed=2)
    for _ in range(50):  # drive until robot 0 holds several hypotheses
        obs, *_ = env.step(runner.act(obs))
        if len(probe._modes([0])[0]) > 1:
            break
    costs = {}
    for select in ("utility", "nearest"):
        p = HypothesisPolicy(select=select, copies=True)
        p.reset(env, seed=2)
        m = p._modes([0])[0]
        poses = np.column_stack([m[:, 1], m[:, 2], np.arctan2(m[:, 4], m[:, 3])])
        st = p.state[0]
        st.lead = poses[0]
        p._plan(0, st, poses, m[:, 0], [])
        assert len(poses) > 1 and st.target is not None
        plan = p.plans[0]
        costs[select] = plan.distances(int(plan.cell_of(poses[0][:2])))[0][
            int(plan.cell_of(st.target))]
    assert costs["nearest"] < costs["utility"]


def _mode_rows(top_weight: float, copy: bool, x: float = 15.0) -> np.ndarray:
    rows = [[top_weight, x, 10.0, 1.0, 0.0, 0.3]]
    if copy:
        rows.append([0.005, 10.0, x, 0.0, 1.0, 0.3])  # its quarter-turn copy
    rows.append([0.03, 3.0, 3.0, 1.0, 0.0, 0.3])
    return np.array(rows)


def test_copies_count_until_a_place_is_tested():
    from policies.scripted.hypothesis import _Robot

    quarter = MapSymmetry(math.pi / 2, (10.0, 10.0), 0.9)
    policy, st = HypothesisPolicy(copies=True), _Robot()
    for _ in range(3):  # the filter is sure (0.95), but its copy is still kept
        assert policy._copies(st, _mode_rows(0.95, True), (quarter,))[0, 0] < 0.5
    st.resolved = True  # (set when a target is reached and the dwell is over)
    assert policy._copies(st, _mode_rows(0.95, True), (quarter,))[0, 0] == pytest.approx(0.95)
    # the main mode jumps: its copies count again
    assert policy._copies(st, _mode_rows(0.95, True, x=16.0), (quarter,))[0, 0] == \
        pytest.approx(0.95)  # within TRACK_M: the same mode
    assert policy._copies(st, _mode_rows(0.95, True, x=18.0), (quarter,))[0, 0] < 0.5
    assert not st.resolved
