"""The scripted policies act on what the robots know, never on the true poses.

Each check shifts the true poses (then restores them) and compares the actions of
two copies of the policy (``actions_with_shifted_truth`` in ``tests/conftest.py``).
The circuit policy's driver steers by the true pose on purpose (a stand-in for
the human driver of Howard's experiment): it is the control that must be caught.
"""

from __future__ import annotations

import numpy as np
import pytest

import coop_loc_env
from coop_loc_env.scenarios.howard import DRIVER
from policies.learning.loader import make_policy
from policies.scripted.circuit import CircuitPolicy
from policies.scripted.dispersal import DispersalPolicy

# policy -> (scenario, overrides)
CASES = {
    "fsm": ("outdoor_terrain", {}),
    "random": ("outdoor_terrain", {}),
    "still": ("outdoor_terrain", {}),
    "dispersal": ("dispersal", {"n_robots": 6}),
    "circuit": ("circuit", {}),
}


def _policy(name: str):
    if name == "dispersal":
        return DispersalPolicy()
    if name == "circuit":
        return CircuitPolicy()
    return make_policy(name)


def _changed_agents(name: str, actions_with_shifted_truth, steps: int = 40) -> set[str]:
    """Agents whose action changed at some checked step when the truth was shifted."""
    scenario, overrides = CASES[name]
    env = coop_loc_env.parallel_env(scenario, max_cycles=steps + 5, **overrides)
    policy = _policy(name)
    obs, _ = env.reset(seed=4)
    policy.reset(env, seed=4)
    rng = np.random.default_rng(1)
    changed: set[str] = set()
    for t in range(steps):
        if t % 4 == 0:
            for agent in env.agents:
                env.camera_readings(agent)  # the lazily built camera records, taken now
            before, after = actions_with_shifted_truth(env, policy, obs, rng)
            changed |= {a for a in env.agents if not np.array_equal(before[a], after[a])}
        obs, *_ = env.step(policy.act(obs))
        if not env.agents:
            break
    return changed


@pytest.mark.parametrize("name", ["fsm", "random", "still", "dispersal"])
def test_policy_never_reads_the_truth(name, actions_with_shifted_truth):
    assert _changed_agents(name, actions_with_shifted_truth) == set()


def test_circuit_driver_reads_the_truth_and_the_others_do_not(actions_with_shifted_truth):
    assert _changed_agents("circuit", actions_with_shifted_truth) == {f"robot_{DRIVER}"}
