"""Noise and calibration parameters of the log replay, and their JSON load/save."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from estimators.team_ekf import MotionNoise

__all__ = [
    "DEFAULT_NOISE_PATH",
    "PER_ROBOT_KEYS",
    "NoiseParameters",
    "load_noise_parameters",
    "save_noise_parameters",
]

DEFAULT_NOISE_PATH = Path(__file__).resolve().parents[1] / "data" / "mrclam_noise.json"


PER_ROBOT_KEYS = ("v_scale", "w_scale", "bearing_bias_rad", "sensor_x_m", "sensor_y_m")


@dataclass(frozen=True)
class NoiseParameters:
    """Calibration and noise of the motion and measurement models (SI units).

    Motion: commands are delayed by ``odometry_delay_s`` and scaled by
    ``v_scale``/``w_scale``; noise densities ``q = q0 + q1 * |command|``
    (:class:`~estimators.team_ekf.MotionNoise`). Measurements: a reading
    stamped ``t`` refers to time ``t - measurement_delay_s``; range and
    bearing biases are subtracted; the standard deviations are
    ``range_std_a + range_std_b * range`` and ``bearing_std`` (separately for
    landmark and robot targets); the sensor sits at ``(sensor_x_m,
    sensor_y_m)`` in the body frame. ``per_robot`` maps a robot number (as a
    string) to overrides of any of :data:`PER_ROBOT_KEYS` (a per-robot
    calibration; empty = global parameters only). ``gate_prob`` is the chi-square gate
    probability; ``initial_std_xy``/``initial_std_heading`` the prior around
    the initial ground-truth pose.
    """

    odometry_delay_s: float = 0.0
    v_scale: float = 1.0
    w_scale: float = 1.0
    q_v0: float = 1e-4
    q_v1: float = 0.0
    q_w0: float = 1e-3
    q_w1: float = 0.0
    measurement_delay_s: float = 0.0
    range_bias_m: float = 0.0
    bearing_bias_rad: float = 0.0
    landmark_range_std_a: float = 0.05
    landmark_range_std_b: float = 0.03
    landmark_bearing_std: float = 0.01
    robot_range_std_a: float = 0.05
    robot_range_std_b: float = 0.03
    robot_bearing_std: float = 0.01
    sensor_x_m: float = 0.0
    sensor_y_m: float = 0.0
    gate_prob: float = 0.99
    initial_std_xy: float = 0.01
    initial_std_heading: float = 0.01
    per_robot: dict = field(default_factory=dict)
    fitted_on: str = ""

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name in ("fitted_on", "per_robot"):
                continue
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not np.isfinite(value):
                raise ValueError(f"NoiseParameters.{f.name} must be a finite number, got {value!r}")
        for name in ("v_scale", "w_scale", "landmark_bearing_std", "robot_bearing_std"):
            if getattr(self, name) <= 0:
                raise ValueError(f"NoiseParameters.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.gate_prob < 1.0:
            raise ValueError(f"NoiseParameters.gate_prob must be in (0, 1), got {self.gate_prob!r}")
        for rid, over in self.per_robot.items():
            if not str(rid).isdigit() or not isinstance(over, dict):
                raise ValueError(f"NoiseParameters.per_robot: bad entry {rid!r}: {over!r}")
            bad = set(over) - set(PER_ROBOT_KEYS)
            if bad:
                raise ValueError(
                    f"NoiseParameters.per_robot[{rid!r}]: unknown key(s) {sorted(bad)}; "
                    f"allowed: {PER_ROBOT_KEYS}"
                )
            for key, value in over.items():
                if not isinstance(value, (int, float)) or not np.isfinite(value):
                    raise ValueError(
                        f"NoiseParameters.per_robot[{rid!r}][{key!r}] must be finite, got {value!r}"
                    )

    def for_robot(self, robot: int) -> dict[str, float]:
        """The calibration of robot ``robot``: globals overridden by ``per_robot[str(robot)]``."""
        out = {key: float(getattr(self, key)) for key in PER_ROBOT_KEYS}
        out.update(self.per_robot.get(str(robot), {}))
        return out

    @property
    def motion_noise(self) -> MotionNoise:
        """The process-noise model for :class:`OdometryTrack`."""
        return MotionNoise(self.q_v0, self.q_v1, self.q_w0, self.q_w1)

    def measurement_cov(self, range_: float, robot_target: bool) -> np.ndarray:
        """2x2 range-bearing covariance for a reading at range ``range_``."""
        if robot_target:
            sr = self.robot_range_std_a + self.robot_range_std_b * range_
            sb = self.robot_bearing_std
        else:
            sr = self.landmark_range_std_a + self.landmark_range_std_b * range_
            sb = self.landmark_bearing_std
        sr = max(sr, 1e-3)
        return np.array([[sr * sr, 0.0], [0.0, sb * sb]])


def save_noise_parameters(params: NoiseParameters, path: str | Path) -> None:
    """Write ``params`` as JSON."""
    Path(path).write_text(json.dumps(asdict(params), indent=2) + "\n")


def load_noise_parameters(path: str | Path | None = None) -> NoiseParameters:
    """Read parameters written by :func:`save_noise_parameters` (default: the shipped file)."""
    p = Path(path) if path is not None else DEFAULT_NOISE_PATH
    if not p.is_file():
        raise FileNotFoundError(f"noise parameter file not found: {p}")
    try:
        raw = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc})") from None
    known = {f.name for f in fields(NoiseParameters)}
    unknown = set(raw) - known
    if unknown:
        raise ValueError(f"{p}: unknown noise parameter(s) {sorted(unknown)}")
    return NoiseParameters(**raw)
