"""Replay logged multi-robot data through the estimators and score them against ground truth.

Standard protocol (MR.CLAM): start at the latest odometry start of the
robots, initialize each robot at its ground-truth pose there, run through the
time-sorted stream of all robots' measurements (odometry is integrated
between events), and evaluate on a 1 s grid against ground truth interpolated
at the grid times (grid times without ground truth are skipped). Heading is
always estimated, never read from ground truth.

Estimators: ``dead_reckoning`` (odometry only), ``ekf`` (independent
per-robot EKFs with landmark updates), ``ekf_team`` (centralized team EKF that
also fuses robot-to-robot range-bearing measurements), ``mle`` (the online
sliding-window pose-graph MLE of :mod:`estimators.mle_online`, landmarks as
fixed nodes). ``use_landmarks=False`` keeps only robot-to-robot measurements.

Noise parameters (:class:`NoiseParameters`) are fitted from one dataset's
ground truth by :func:`fit_noise_parameters` and stored as JSON; the package
ships one fitted on MR.CLAM dataset 6 *outside* the standard evaluation window
(see ``estimators/data/mrclam_noise.json``, field ``fitted_on``).

Landmark readings pass a screen first
(:class:`~estimators.replay.landmark_screen.LandmarkScreen`, ``screen_landmarks=False``
switches it off): a landmark that several robots find off the map the same way has that
offset counted as map uncertainty.

Modules: :mod:`~estimators.replay.noise_model` (the parameters and their
JSON files), :mod:`~estimators.replay.runner` (replay and evaluation),
:mod:`~estimators.replay.calibration` (fitting the parameters),
:mod:`~estimators.replay.landmark_screen` (the screen).
"""

from estimators.replay.calibration import (
    TUNING_GRID,
    fit_noise_parameters,
    scale_noise,
    tune_inflation,
)
from estimators.replay.landmark_screen import LandmarkScreen
from estimators.replay.noise_model import (
    DEFAULT_NOISE_PATH,
    PER_ROBOT_KEYS,
    NoiseParameters,
    load_noise_parameters,
    save_noise_parameters,
)
from estimators.replay.runner import ESTIMATORS, ReplayResult, evaluate, replay

__all__ = [
    "ESTIMATORS",
    "DEFAULT_NOISE_PATH",
    "LandmarkScreen",
    "PER_ROBOT_KEYS",
    "TUNING_GRID",
    "NoiseParameters",
    "ReplayResult",
    "evaluate",
    "fit_noise_parameters",
    "load_noise_parameters",
    "replay",
    "save_noise_parameters",
    "scale_noise",
    "tune_inflation",
]
