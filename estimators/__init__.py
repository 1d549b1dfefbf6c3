"""State estimators for cooperative localization: pure numpy/scipy, no environment import.

Everything here consumes plain arrays, so it runs on simulated data and on
real robot logs alike.
"""

from estimators.geometry import compose_relative, relative_pose, wrap_angle

__all__ = ["compose_relative", "relative_pose", "wrap_angle"]
