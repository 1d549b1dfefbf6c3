"""World stepping: the direct pymunk calls match pymunk's public API."""

import numpy as np

import coop_loc_env


def _run(direct: bool) -> tuple[np.ndarray, np.ndarray]:
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4, max_cycles=10**9)
    env.reset(seed=3)
    if not direct:
        env.world._direct = None
    rng = np.random.default_rng(0)
    poses, contacts = [], []
    for _ in range(150):
        acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        _, _, _, _, infos = env.step(acts)
        poses.append(env.world.poses.copy())
        contacts.append([infos[a]["collisions"] for a in env.possible_agents if a in infos])
    return np.array(poses), np.array(contacts, dtype=object)


def test_direct_batch_calls_step_like_the_public_api():
    env = coop_loc_env.parallel_env("outdoor_terrain", n_robots=4)
    env.reset(seed=0)
    assert env.world._direct is not None  # this pymunk exposes the expected internals
    (pa, ca), (pb, cb) = _run(True), _run(False)
    np.testing.assert_array_equal(pa, pb)
    assert all(list(x) == list(y) for x, y in zip(ca, cb, strict=True))
