"""ParticleTeam: the flat arrays a team of filters shares, and each filter's view of them."""

from __future__ import annotations

import numpy as np

from estimators.mcl.batch import predict_batch, weigh_batch
from estimators.mcl.filter import MCLConfig, ParticleFilter
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.team import ParticleTeam


def team_of_three() -> list[ParticleFilter]:
    grid = OccupancyGrid.from_shapes((6.0, 4.0), 0.1, border=True)
    cfg = MCLConfig(n_particles=200)
    filters = [ParticleFilter(grid, np.random.default_rng(i), cfg) for i in range(3)]
    filters[1].init_uniform(300)
    return filters


def test_gather_makes_every_state_a_view_and_reuses_it():
    filters = team_of_three()
    team = ParticleTeam.gather(filters)
    np.testing.assert_array_equal(team.ends, [200, 500, 700])
    np.testing.assert_array_equal(team.starts, [0, 200, 500])
    assert team.state.shape == (3 * 700,) and team.state.dtype == np.float32
    for pf, start, end in zip(filters, team.starts, team.ends, strict=True):
        assert pf.particle_set.state.base is team.state
        np.testing.assert_array_equal(pf.particle_set.state.ravel(),
                                      team.state[3 * start:3 * end])
    assert ParticleTeam.gather(filters).state is team.state  # in place: no copy
    predict_batch(filters, np.zeros((3, 3)))
    assert ParticleTeam.gather(filters).state is team.state  # moved in place
    filters[2].init_uniform()  # a replaced state is copied in again
    assert ParticleTeam.gather(filters).state is not team.state


def test_team_weights_origins_and_ess_follow_the_filters():
    filters = team_of_three()
    team = ParticleTeam.gather(filters)
    np.testing.assert_array_equal(team.weights(),
                                  np.concatenate([pf.weights for pf in filters]))
    np.testing.assert_array_equal(team.origins, [pf.state_origin for pf in filters])
    np.testing.assert_allclose(team.ess, [200, 300, 200])
    assert team.rngs == [pf.rng for pf in filters]
    fixes = np.stack([pf.fix_row((1.0, 1.0), 0.5) for pf in filters])
    weigh_batch(filters, None, None, None, fixes)
    w = ParticleTeam.gather(filters).weights()
    assert all(pf.particle_set.weights.base is w for pf in filters)  # one weighting's output
    np.testing.assert_allclose(team.ess, [pf.ess for pf in filters])
    assert team.ess[0] < 200


def test_a_filter_alone_is_a_team_of_one():
    pf = team_of_three()[0]
    team = ParticleTeam.alone(pf)
    assert team.members == (pf,) and team.sets == [pf.particle_set]
    np.testing.assert_array_equal(team.ends, [pf.n_particles])
    assert np.shares_memory(team.state, pf.particle_set.state)
