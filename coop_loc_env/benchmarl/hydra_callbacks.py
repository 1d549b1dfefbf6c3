"""A hydra callback of the coop_loc BenchMARL tasks: missing logger packages stop the run
with one line (BenchMARL would fail later, inside its setup, with a long traceback)."""

from __future__ import annotations

import importlib.util
import sys
from typing import Any

from hydra.experimental.callback import Callback

#: The package each BenchMARL logger needs (``csv`` needs none beyond BenchMARL).
LOGGER_PACKAGES = {"wandb": "wandb", "tensorboard": "tensorboard", "mlflow": "mlflow"}


def missing_logger_packages(loggers: list[str]) -> list[str]:
    """The packages of ``loggers`` that are not installed."""
    wanted = [LOGGER_PACKAGES[name] for name in loggers if name in LOGGER_PACKAGES]
    return [pkg for pkg in wanted if importlib.util.find_spec(pkg) is None]


class CheckLoggers(Callback):
    """Before the job: one line on stderr and exit status 2 if a logger's package is
    missing."""

    def on_job_start(self, config: Any, **kwargs: Any) -> None:
        loggers = list(config.get("experiment", {}).get("loggers", []) or [])
        missing = missing_logger_packages(loggers)
        if missing:
            print(f"error: experiment.loggers={loggers} needs {', '.join(missing)}, which is "
                  f"not installed: pip install {' '.join(missing)}, or log to CSV files only "
                  f"with experiment.loggers=[csv]", file=sys.stderr)
            sys.exit(2)
