"""Shared test configuration."""

import os

# One BLAS thread: the suite runs on 2 cores and small solves only lose from threading.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import matplotlib  # noqa: E402

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.pop("DISPLAY", None)
matplotlib.use("Agg")
