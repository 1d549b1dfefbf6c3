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


@pytest.fixture
def script_main():
    """Load ``scripts/<name>.py`` and return its ``main`` function."""

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module.main

    return load


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
