"""Multi-robot Monte Carlo localization (Fox et al.) on occupancy grids.

:class:`~estimators.mcl.filter.ParticleFilter` is one robot's view of a
:class:`~estimators.mcl.team.ParticleTeam`, the flat arrays that the compiled
sampling (:mod:`~estimators.mcl.sampling`), weighting
(:mod:`~estimators.mcl.weighting`) and team passes (:mod:`~estimators.mcl.batch`)
update. Sensor models: :mod:`~estimators.mcl.likelihood_field`,
:mod:`~estimators.mcl.beam_table`; detections between robots:
:mod:`~estimators.mcl.detection_transfer` (density trees,
:mod:`~estimators.mcl.density_tree`) checked by
:mod:`~estimators.mcl.detection_consistency`.
"""

from estimators.mcl.config import MCLConfig, ParticleBelief, ParticleMotionNoise
from estimators.mcl.density_tree import DensityTree
from estimators.mcl.detection_transfer import (
    DetectionTransfer,
    RobotDetection,
    TransferConfig,
    detection_from_measurement,
)
from estimators.mcl.features import belief_feature_names
from estimators.mcl.filter import ParticleFilter
from estimators.mcl.occupancy import OccupancyGrid
from estimators.mcl.team import ParticleSet, ParticleTeam

__all__ = [
    "DensityTree",
    "DetectionTransfer",
    "MCLConfig",
    "OccupancyGrid",
    "ParticleBelief",
    "ParticleFilter",
    "ParticleMotionNoise",
    "ParticleSet",
    "ParticleTeam",
    "RobotDetection",
    "TransferConfig",
    "belief_feature_names",
    "detection_from_measurement",
]
