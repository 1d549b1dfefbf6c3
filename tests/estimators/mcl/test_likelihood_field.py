"""The likelihood field's table holds the default model: a Gaussian of 0.2 m around
the nearest wall mixed with a uniform floor."""

from __future__ import annotations

import math

import numpy as np

from estimators.mcl.config import MCLConfig
from estimators.mcl.likelihood_field import LF_POWER, build_lf_field
from estimators.mcl.occupancy import OccupancyGrid


def test_default_field_falls_off_as_a_gaussian_of_twenty_centimetres():
    """Along a row leaving a wall, the table's per-beam log-likelihood is
    ``log(z_hit N(d; 0, 0.2) + z_rand / max_range)``: the default sigma decides how fast
    it falls (0.22 m would give 0.3 nats more at 0.4 m than at 0.1 m, far above the float32
    rounding)."""
    occupied = np.zeros((20, 40), dtype=bool)
    occupied[:, :5] = True  # a wall on the left, 0.5 m thick, cells of 0.1 m
    grid = OccupancyGrid(occupied, 0.1)
    cfg = MCLConfig()
    max_range = 5.0
    field = build_lf_field(grid, cfg, max_range)
    loglik = field.table[:field.offset].reshape(field.nyp, field.nxp)
    row = loglik[field.pad + 10, field.pad + 5:field.pad + 15].astype(float) * LF_POWER
    dist = np.minimum(grid.distance_field(field.pad), cfg.lf_max_dist)
    d = dist[field.pad + 10, field.pad + 5:field.pad + 15]
    assert d[0] > 0 and np.all(np.diff(d) > 0)  # free cells moving away from the wall

    def model(sigma: float) -> np.ndarray:
        gauss = np.exp(-0.5 * (d / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi))
        return np.log(cfg.lf_z_hit * gauss + cfg.lf_z_rand / max_range)

    want = model(0.2)
    # the table stores the log-likelihood less its maximum: compare differences
    np.testing.assert_allclose(row - row[0], want - want[0], atol=1e-4)
    assert np.abs((model(0.22) - model(0.22)[0]) - (row - row[0])).max() > 0.05
