"""State estimators for cooperative localization: numpy/scipy (and a few numba loops for the
particle filters), no environment import.

Everything here consumes plain arrays, so it runs on simulated data and on
real robot logs alike:

- :class:`PoseEKF` — per-robot EKFs in numpy batches (Madhavan et al.), with
  :class:`TeamEKF` the centralized full-covariance variant used on real logs;
  :class:`GateMonitor` (simulated sensors) and :class:`Relocalizer` (landmark
  readings) recover them from validation-gate lock-out;
- :class:`ParticleFilter`, :class:`DensityTree`, :class:`DetectionTransfer` —
  multi-robot Monte Carlo localization (Fox et al.), with per-map beam-model
  tables (:mod:`estimators.mcl.beam_table`) and team-level batched updates
  (:mod:`estimators.mcl.batch`);
- :class:`PoseGraph`, :class:`TeamMLE` — maximum-likelihood team localization
  (Howard et al.) and its Eq. 15 metrics;
- :class:`TerrainMap` — elevation-gradient terrain mapping;
- :func:`load_mrclam` — the UTIAS MR.CLAM log format.
"""

from estimators.ekf import Belief, PoseEKF, chi2_threshold
from estimators.gating import GateMonitor
from estimators.geometry import compose_relative, relative_pose, wrap_angle, wrap_angle_in_place
from estimators.mcl.density_tree import DensityTree
from estimators.mcl.detection_transfer import (
    DetectionTransfer,
    RobotDetection,
    TransferConfig,
    detection_from_measurement,
)
from estimators.mcl.filter import MCLConfig, ParticleFilter, belief_feature_names
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mle_online import TeamMLE
from estimators.mrclam import load_mrclam
from estimators.pose_graph import PoseGraph, marginal_covariances, optimize
from estimators.relative_metrics import (
    relative_error_dict,
    relative_errors,
    relative_errors_per_robot,
)
from estimators.relocalization import Relocalizer
from estimators.team_ekf import TeamEKF
from estimators.terrain_fusion import fuse_elevation, fusion_weights, paper_delta_z
from estimators.terrain_map import TerrainMap

__all__ = [
    "Belief",
    "DensityTree",
    "DetectionTransfer",
    "GateMonitor",
    "MCLConfig",
    "OccupancyGrid",
    "ParticleFilter",
    "PoseEKF",
    "PoseGraph",
    "Relocalizer",
    "RobotDetection",
    "TeamEKF",
    "TeamMLE",
    "TerrainMap",
    "TransferConfig",
    "belief_feature_names",
    "chi2_threshold",
    "compose_relative",
    "detection_from_measurement",
    "fuse_elevation",
    "fusion_weights",
    "load_mrclam",
    "marginal_covariances",
    "optimize",
    "paper_delta_z",
    "relative_error_dict",
    "relative_errors",
    "relative_errors_per_robot",
    "relative_pose",
    "wrap_angle",
    "wrap_angle_in_place",
]
