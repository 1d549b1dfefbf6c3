"""Torch's intra-op thread count for this project's trainers, evaluators and TorchRL /
BenchMARL entry points, chosen in one place.

The networks here are small (a few layers of 64-256 units) and the env steps on the
CPU between forward passes, so torch's default (one thread per core) mostly makes the
threads wait for each other and for the env: on a shared 2-core machine a short BenchMARL
run took 2.1x as long with torch's default of 2 threads as with 1 (docs/scaling.md,
``python scripts/bench/torch_threads.py``). :data:`TORCH_THREADS` is the
project's choice; the environment variable :data:`THREADS_ENV` overrides it
(``COOP_LOC_TORCH_THREADS=4``), and ``COOP_LOC_TORCH_THREADS=0`` leaves torch's own
setting alone.
"""

from __future__ import annotations

import os

#: Torch threads used by training, evaluation and the TorchRL / BenchMARL entry points.
TORCH_THREADS = 1
#: The environment variable that overrides :data:`TORCH_THREADS` (0: torch's default).
THREADS_ENV = "COOP_LOC_TORCH_THREADS"


def torch_threads(default: int = TORCH_THREADS) -> int | None:
    """The thread count to use: :data:`THREADS_ENV` if set (``None`` for 0: leave torch's
    setting), else ``default``; raises ``ValueError`` on a value that is not an integer
    >= 0."""
    raw = os.environ.get(THREADS_ENV, "").strip()
    if not raw:
        return default
    try:
        n = int(raw)
    except ValueError:
        n = -1
    if n < 0:
        raise ValueError(f"{THREADS_ENV} must be an integer >= 0 (0: torch's default), "
                         f"got {raw!r}")
    return n or None


def set_torch_threads(default: int = TORCH_THREADS) -> int:
    """Apply :func:`torch_threads` to torch (imported here); returns the threads in use."""
    import torch

    n = torch_threads(default)
    if n is not None and torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return torch.get_num_threads()
