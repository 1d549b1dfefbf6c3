"""Micro-benchmark of one robot's MCL update (motion + likelihood-field laser + resample).

``bench_mcl()`` returns timings in microseconds for one full update with 1000
particles and 30 beams, next to a bare ``numpy.take`` of 30,000 floats from the
same log-likelihood field, measured in the same run, and their ratio. The lead's
``scripts/benchmark.py`` imports it; ``python scripts/_bench_mcl.py`` prints it.
"""

from __future__ import annotations

import timeit

import numpy as np

from estimators.occupancy import OccupancyGrid
from estimators.particle_filter import MCLConfig, ParticleFilter

__all__ = ["bench_mcl", "bench_map"]


def bench_map(resolution: float = 0.05) -> OccupancyGrid:
    """A 20 m x 12 m walled room with a few boxes (the benchmark's map)."""
    width, height = 20.0, 12.0
    nx, ny = int(round(width / resolution)), int(round(height / resolution))
    occ = np.zeros((ny, nx), dtype=bool)
    occ[0, :] = occ[-1, :] = occ[:, 0] = occ[:, -1] = True
    for x0, y0, x1, y1 in [(3, 3, 5, 4), (10, 6, 11, 12), (14, 2, 17, 3), (7, 0, 7.5, 4)]:
        rows = slice(int(y0 / resolution), int(y1 / resolution))
        occ[rows, int(x0 / resolution):int(x1 / resolution)] = True
    return OccupancyGrid(occ, resolution, (0.0, 0.0))


def _median_us(fn, number: int, repeat: int) -> float:
    times = timeit.repeat(fn, number=number, repeat=repeat)
    return float(np.median(times) / number * 1e6)


def bench_mcl(
    n_particles: int = 1000, n_beams: int = 30, number: int = 200, repeat: int = 7, seed: int = 0
) -> dict[str, float]:
    """Time one full MCL update and a bare ``take`` of ``n_particles * n_beams`` floats.

    Returns a dict with ``mcl_update_us`` (predict + likelihood-field update +
    low-variance resample, fixed particle count), its parts
    (``mcl_predict_us``, ``mcl_laser_us``, ``mcl_resample_us``),
    ``take_us`` (``np.take`` of the same number of random cells of the same
    field) and ``mcl_ratio = mcl_update_us / take_us``. Also ``mcl_kld_update_us``:
    the same update with KLD-sampling on (n_max = n_particles). Medians over
    ``repeat`` runs of ``number`` calls.
    """
    grid = bench_map()
    rng = np.random.default_rng(seed)
    cfg = MCLConfig(n_particles=n_particles, augmented=False)
    pf = ParticleFilter(grid, rng, cfg)
    pose = np.array([2.0, 2.0, 0.3])
    pf.init_gaussian(pose, np.diag([0.3, 0.3, 0.1]) ** 2)
    angles = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    max_range = 10.0
    ranges = grid.simulate_scan(pose, angles, max_range)
    lf = pf._lf_field(max_range)  # the same table the update gathers from
    field = lf.table
    idx = rng.integers(0, lf.offset, size=n_particles * n_beams)

    sign = [1.0]

    def full() -> None:
        sign[0] = -sign[0]  # drive back and forth so particles stay near the scan's pose
        pf.predict_odometry(0.3 * sign[0], 0.1, 0.1)
        pf.update_likelihood_field(ranges, angles, max_range)
        pf.resample()

    def predict() -> None:
        sign[0] = -sign[0]
        pf.predict_odometry(0.3 * sign[0], 0.1, 0.1)

    def laser() -> None:
        pf.update_likelihood_field(ranges, angles, max_range)

    def resample() -> None:
        pf.resample()

    def take() -> None:
        np.take(field, idx)

    full()  # warm the caches (field construction)
    out = {
        "mcl_update_us": _median_us(full, number, repeat),
        "take_us": _median_us(take, number, repeat),
        "mcl_predict_us": _median_us(predict, number, repeat),
        "mcl_laser_us": _median_us(laser, number, repeat),
        "mcl_resample_us": _median_us(resample, number, repeat),
    }
    out["mcl_ratio"] = out["mcl_update_us"] / out["take_us"]
    kcfg = MCLConfig(n_particles=n_particles, augmented=False, adaptive=True,
                     n_min=min(100, n_particles), n_max=n_particles)
    kpf = ParticleFilter(grid, np.random.default_rng(seed), kcfg)
    kpf.init_gaussian(pose, np.diag([0.3, 0.3, 0.1]) ** 2)

    def full_kld() -> None:
        sign[0] = -sign[0]
        kpf.predict_odometry(0.3 * sign[0], 0.1, 0.1)
        kpf.update_likelihood_field(ranges, angles, max_range)
        kpf.resample()

    full_kld()
    out["mcl_kld_update_us"] = _median_us(full_kld, number, repeat)
    return out


def main() -> None:
    """Print the figures."""
    for key, val in bench_mcl().items():
        print(f"{key:>20s}: {val:10.2f}")


if __name__ == "__main__":
    main()
