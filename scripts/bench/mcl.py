"""Micro-benchmark of one robot's MCL update (motion + likelihood-field laser + resample).

``bench_mcl()`` returns timings in microseconds for one full update with 1000
particles and 30 beams, next to a bare ``numpy.take`` of 30,000 floats from the
same log-likelihood field, measured in the same run, and their ratio.
``scripts/benchmark.py`` imports it; ``python scripts/bench/mcl.py`` prints it.
"""

from __future__ import annotations

import sys
import time
import timeit
from collections.abc import Callable

import numpy as np

from coop_loc_env.cli import ScriptParser, run_script
from estimators.mcl.filter import MCLConfig, ParticleFilter
from estimators.mcl.occupancy import OccupancyGrid

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


def _interleaved_us(fns: dict[str, Callable[[], None]], number: int, repeat: int
                    ) -> dict[str, float]:
    """Per-call microseconds of each function: best of ``repeat`` interleaved rounds.

    Timed with the process CPU clock (``time.process_time``), so time spent
    descheduled on a shared machine does not count; rounds alternate between
    the functions so that cache and frequency effects hit all of them alike;
    the minimum over rounds is the least disturbed one.
    """
    best = {name: np.inf for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t = timeit.Timer(fn, timer=time.process_time).timeit(number=number) / number * 1e6
            best[name] = min(best[name], t)
    return best


def _naive_update(state: np.ndarray, field2d: np.ndarray, grid: OccupancyGrid, ranges: np.ndarray,
                  angles: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The same update as usually written in numpy (for comparison only): float64
    broadcasting per particle and beam, 2D fancy indexing with bounds clipping,
    log-sum-exp weights and ``rng.choice`` resampling."""
    n = state.shape[0]
    noise = rng.normal(0.0, [0.01, 0.015, 0.01], size=(n, 3))
    th = state[:, 2] + noise[:, 0]
    state = state.copy()
    state[:, 0] += (0.03 + noise[:, 1]) * np.cos(th)
    state[:, 1] += (0.03 + noise[:, 1]) * np.sin(th)
    state[:, 2] = th + noise[:, 2]
    ang = state[:, 2:3] + angles[None, :]
    ex = state[:, 0:1] + ranges[None, :] * np.cos(ang)
    ey = state[:, 1:2] + ranges[None, :] * np.sin(ang)
    ix = np.clip(np.floor((ex - grid.origin[0]) / grid.resolution).astype(int), 0,
                 field2d.shape[1] - 1)
    iy = np.clip(np.floor((ey - grid.origin[1]) / grid.resolution).astype(int), 0,
                 field2d.shape[0] - 1)
    loglik = field2d[iy, ix].sum(axis=1)
    w = np.exp(loglik - loglik.max())
    w /= w.sum()
    return state[rng.choice(n, size=n, p=w)]


_INIT_COV = np.diag([0.3, 0.3, 0.1]) ** 2  # initial spread around the benchmark's pose


def _started_filter(grid: OccupancyGrid, rng: np.random.Generator, cfg: MCLConfig,
                    pose: np.ndarray) -> ParticleFilter:
    """A filter of ``cfg`` on ``grid`` with its particles spread around ``pose``."""
    pf = ParticleFilter(grid, rng, cfg)
    pf.init_gaussian(pose, _INIT_COV)
    return pf


def _full_update(pf: ParticleFilter, sign: list[float], ranges: np.ndarray, angles: np.ndarray,
                 max_range: float) -> Callable[[], None]:
    """One predict + likelihood-field update + resample of ``pf``; ``sign`` (shared by all
    the timed filters) flips each call to drive back and forth, so particles stay near
    the scan's pose."""
    def full() -> None:
        sign[0] = -sign[0]
        pf.predict_odometry(0.3 * sign[0], 0.1, 0.1)
        pf.update_likelihood_field(ranges, angles, max_range)
        pf.resample()
    return full


def _naive_field(grid: OccupancyGrid, cfg: MCLConfig, max_range: float) -> np.ndarray:
    """The likelihood-field log-likelihoods as a 2D float64 array (for the numpy update)."""
    dist = np.minimum(grid.distance_field(), cfg.lf_max_dist)
    return np.log(cfg.lf_z_hit * np.exp(-0.5 * (dist / cfg.lf_sigma) ** 2)
                  / (cfg.lf_sigma * np.sqrt(2 * np.pi)) + cfg.lf_z_rand / max_range)


def bench_mcl(
    n_particles: int = 1000, n_beams: int = 30, number: int = 200, repeat: int = 7, seed: int = 0
) -> dict[str, float]:
    """Time one full MCL update and a bare ``take`` of ``n_particles * n_beams`` floats.

    Returns a dict with ``mcl_update_us`` (predict + likelihood-field update +
    low-variance resample, fixed particle count, no random injection), its
    parts (``mcl_predict_us``, ``mcl_laser_us``, ``mcl_resample_us``),
    ``take_us`` (``np.take`` of the same number of random cells of the same
    field) and ``mcl_ratio = mcl_update_us / take_us``. Also
    ``mcl_kld_update_us`` (KLD-sampling on, n_max = n_particles) and
    ``mcl_default_update_us`` (default config: augmented MCL and 3 % random
    injection, which draws uniform poses each resample), and
    ``naive_update_us`` / ``naive_ratio``: the same update as usually written
    in numpy, for comparison. Best of ``repeat`` interleaved rounds of
    ``number`` calls. The parts are timed in isolation (the laser part then
    gathers the same, cache-hot cells every call), so they add up to less
    than ``mcl_update_us``, where the particles move between gathers.
    """
    grid = bench_map()
    rng = np.random.default_rng(seed)
    cfg = MCLConfig(n_particles=n_particles, augmented=False, random_fraction=0.0)
    pose = np.array([2.0, 2.0, 0.3])
    pf = _started_filter(grid, rng, cfg, pose)
    angles = np.linspace(-np.pi, np.pi, n_beams, endpoint=False)
    max_range = 10.0
    ranges = grid.simulate_scan(pose, angles, max_range)
    lf = pf.lf_field(max_range)  # the same table the update gathers from
    field = lf.table
    idx = rng.integers(0, lf.offset, size=n_particles * n_beams)

    sign = [1.0]
    full = _full_update(pf, sign, ranges, angles, max_range)

    def predict() -> None:
        sign[0] = -sign[0]
        pf.predict_odometry(0.3 * sign[0], 0.1, 0.1)

    full()  # warm the caches (field construction)
    kcfg = MCLConfig(n_particles=n_particles, augmented=False, random_fraction=0.0,
                     adaptive=True, n_min=min(100, n_particles), n_max=n_particles)
    kpf = _started_filter(grid, np.random.default_rng(seed), kcfg, pose)
    dpf = _started_filter(grid, np.random.default_rng(seed), MCLConfig(n_particles=n_particles),
                          pose)
    full_kld = _full_update(kpf, sign, ranges, angles, max_range)
    full_default = _full_update(dpf, sign, ranges, angles, max_range)
    full_kld()
    full_default()
    field2d = _naive_field(grid, pf.config, max_range)
    naive_state = [pf.particles.copy()]
    naive_rng = np.random.default_rng(seed)

    def naive() -> None:
        naive_state[0] = _naive_update(naive_state[0], field2d, grid, ranges, angles, naive_rng)

    times = _interleaved_us(
        {"mcl_update_us": full, "take_us": lambda: np.take(field, idx),
         "mcl_predict_us": predict,
         "mcl_laser_us": lambda: pf.update_likelihood_field(ranges, angles, max_range),
         "mcl_resample_us": pf.resample, "mcl_kld_update_us": full_kld,
         "mcl_default_update_us": full_default, "naive_update_us": naive},
        number, repeat,
    )
    out = dict(times)
    out["mcl_ratio"] = out["mcl_update_us"] / out["take_us"]
    out["naive_ratio"] = out["naive_update_us"] / out["take_us"]
    return out


def main(argv: list[str] | None = None) -> None:
    """Print the figures."""
    parser = ScriptParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, default=1000, help="particles of the filter")
    parser.add_argument("--beams", type=int, default=30, help="laser beams per scan")
    parser.add_argument("--number", type=int, default=200, help="calls per timing round")
    parser.add_argument("--repeat", type=int, default=7, help="interleaved rounds (best kept)")
    args = parser.parse_args(argv)
    if min(args.particles, args.beams, args.number, args.repeat) < 1:
        print("error: --particles, --beams, --number and --repeat must be >= 1", file=sys.stderr)
        sys.exit(2)
    for key, val in bench_mcl(args.particles, args.beams, args.number, args.repeat).items():
        print(f"{key:>20s}: {val:10.2f}")


if __name__ == "__main__":
    sys.exit(run_script(main))
