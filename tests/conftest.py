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
