"""Loader for the UTIAS Multi-Robot Cooperative Localization and Mapping (MR.CLAM) logs.

Dataset: K. Y. K. Leung, Y. Halpern, T. D. Barfoot, H. H. T. Liu, "The UTIAS
Multi-Robot Cooperative Localization and Mapping Dataset", IJRR 30(8), 2011.

A dataset directory holds, for robots ``N = 1..5``, ``RobotN_Odometry.dat``
(time, v, w), ``RobotN_Measurement.dat`` (time, *barcode*, range, bearing),
``RobotN_Groundtruth.dat`` (time, x, y, heading), plus ``Barcodes.dat``
(subject -> barcode) and ``Landmark_Groundtruth.dat`` (subject, x, y, sx, sy).
Lines starting with ``#`` are comments. The measurement column named
"Subject #" holds barcode numbers; they are mapped to subjects here, and
barcodes that are in no table are dropped and counted.

All times are shifted by a common origin (the earliest time stamp in any
robot file) so that they stay small; ``MrclamDataset.time_origin`` keeps the
absolute Unix time of that origin. Nothing here depends on the environment.
"""

from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimators.geometry import wrap_angle

__all__ = [
    "MrclamDataset",
    "RobotLog",
    "interpolate_groundtruth",
    "load_mrclam",
    "read_table",
]


@dataclass(frozen=True)
class RobotLog:
    """One robot's logs, times relative to the dataset's ``time_origin``.

    ``odometry``: ``(N, 3)`` rows ``t, v, w``; ``measurements``: ``(M, 4)``
    rows ``t, subject, range, bearing`` (subjects, not barcodes);
    ``groundtruth``: ``(G, 4)`` rows ``t, x, y, heading``.
    """

    subject: int
    odometry: np.ndarray
    measurements: np.ndarray
    groundtruth: np.ndarray


@dataclass(frozen=True)
class MrclamDataset:
    """A loaded MR.CLAM dataset.

    ``robots`` maps robot subject number to its :class:`RobotLog`;
    ``landmarks`` maps landmark subject number to ``(x, y)``;
    ``landmark_std`` to the surveyed ``(sx, sy)``; ``barcodes`` maps barcode
    to subject; ``unknown_barcodes`` counts skipped measurements per barcode.
    """

    path: Path
    robots: dict[int, RobotLog]
    landmarks: dict[int, np.ndarray]
    landmark_std: dict[int, np.ndarray]
    barcodes: dict[int, int]
    unknown_barcodes: dict[int, int] = field(default_factory=dict)
    time_origin: float = 0.0

    @property
    def robot_ids(self) -> list[int]:
        """Robot subject numbers in increasing order."""
        return sorted(self.robots)

    def latest_odometry_start(self) -> float:
        """The first time at which every robot has odometry (the protocol's start)."""
        return max(float(log.odometry[0, 0]) for log in self.robots.values())

    def end_time(self) -> float:
        """The last odometry time common to all robots."""
        return min(float(log.odometry[-1, 0]) for log in self.robots.values())


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, text) of every non-comment, non-blank line."""
    with open(path, encoding="ascii", errors="replace") as fh:
        return [
            (i, line)
            for i, line in enumerate(fh, start=1)
            if line.strip() and not line.lstrip().startswith("#")
        ]


def _locate_bad_line(path: Path, ncols: int) -> str:
    """Describe the first line of ``path`` that is not ``ncols`` finite numbers."""
    for lineno, line in _data_lines(path):
        fields = line.split()
        if len(fields) != ncols:
            return (
                f"{path}:{lineno}: expected {ncols} columns, got {len(fields)} "
                f"(malformed or truncated line {line.strip()!r})"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            return f"{path}:{lineno}: not a number in line {line.strip()!r}"
        if not np.all(np.isfinite(values)):
            return f"{path}:{lineno}: non-finite value in line {line.strip()!r}"
    return f"{path}: could not parse file"


def read_table(path: str | Path, ncols: int, *, time_column: bool = True) -> np.ndarray:
    """Read a whitespace-separated MR.CLAM table with ``ncols`` numeric columns.

    Raises ``FileNotFoundError`` naming the file if it is missing, and
    ``ValueError`` naming the file and line for a malformed, truncated or
    non-finite line, or (when ``time_column``) a time that goes backwards.
    Equal consecutive times are allowed (several detections per image).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MR.CLAM file not found: {path}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an empty file warns; make it an error
            data = np.loadtxt(path, comments="#", ndmin=2, dtype=float)
    except (ValueError, UserWarning):
        if not _data_lines(path):
            raise ValueError(f"{path}: no data lines") from None
        raise ValueError(_locate_bad_line(path, ncols)) from None
    if data.shape[1] != ncols or not np.all(np.isfinite(data)):
        raise ValueError(_locate_bad_line(path, ncols))
    if time_column and len(data) > 1:
        back = np.flatnonzero(np.diff(data[:, 0]) < 0)
        if back.size:
            k = int(back[0]) + 1
            lineno = _data_lines(path)[k][0]
            raise ValueError(
                f"{path}:{lineno}: non-monotonic time {data[k, 0]!r} after {data[k - 1, 0]!r}"
            )
    return data


def load_mrclam(path: str | Path, robots: tuple[int, ...] | None = None) -> MrclamDataset:
    """Load an MR.CLAM dataset directory.

    ``robots`` selects robot subject numbers (default: every ``N`` with any
    ``RobotN_*.dat`` file; each needs all three files).
    Measurements with barcodes missing from ``Barcodes.dat`` are skipped and
    counted in ``unknown_barcodes``; measurements of subjects that are neither
    a loaded robot nor a surveyed landmark are counted there as well.
    """
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"MR.CLAM dataset directory not found: {root}")
    bar = read_table(root / "Barcodes.dat", 2, time_column=False)
    barcodes: dict[int, int] = {}
    for subject, code in bar:
        if subject != int(subject) or code != int(code):
            raise ValueError(f"{root / 'Barcodes.dat'}: non-integer entry {subject!r} {code!r}")
        barcodes[int(code)] = int(subject)
    lm = read_table(root / "Landmark_Groundtruth.dat", 5, time_column=False)
    landmarks = {int(r[0]): r[1:3].copy() for r in lm}
    landmark_std = {int(r[0]): r[3:5].copy() for r in lm}

    if robots is None:
        found = set()
        for p in root.glob("Robot*_*.dat"):
            stem = p.name[len("Robot") :].split("_", 1)[0]
            if stem.isdigit():
                found.add(int(stem))
        if not found:
            raise FileNotFoundError(f"no RobotN_*.dat files in {root}")
        robots = tuple(sorted(found))
    raw: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for rid in robots:
        raw[rid] = (
            read_table(root / f"Robot{rid}_Odometry.dat", 3),
            read_table(root / f"Robot{rid}_Measurement.dat", 4),
            read_table(root / f"Robot{rid}_Groundtruth.dat", 4),
        )
    origin = min(min(o[0, 0], m[0, 0], g[0, 0]) for o, m, g in raw.values())

    code_to_subject = np.vectorize(lambda c: barcodes.get(int(c), -1), otypes=[int])
    unknown: Counter[int] = Counter()
    logs: dict[int, RobotLog] = {}
    known_subjects = set(robots) | set(landmarks)
    for rid, (odo, meas, gt) in raw.items():
        codes = meas[:, 1]
        if np.any(codes != np.round(codes)):
            bad = int(np.flatnonzero(codes != np.round(codes))[0])
            raise ValueError(
                f"{root / f'Robot{rid}_Measurement.dat'}: non-integer barcode {codes[bad]!r}"
            )
        subjects = code_to_subject(codes) if len(codes) else np.zeros(0, int)
        keep = np.isin(subjects, list(known_subjects)) & (subjects != rid)
        unknown.update(int(c) for c in codes[~keep])
        m = meas[keep].copy()
        m[:, 1] = subjects[keep]
        m[:, 3] = wrap_angle(m[:, 3])
        o = odo.copy()
        g = gt.copy()
        o[:, 0] -= origin
        m[:, 0] -= origin
        g[:, 0] -= origin
        g[:, 3] = wrap_angle(g[:, 3])
        logs[rid] = RobotLog(rid, o, m, g)
    return MrclamDataset(
        path=root,
        robots=logs,
        landmarks=landmarks,
        landmark_std=landmark_std,
        barcodes=barcodes,
        unknown_barcodes=dict(sorted(unknown.items())),
        time_origin=float(origin),
    )


def interpolate_groundtruth(
    groundtruth: np.ndarray, times: np.ndarray, max_gap: float = 0.25
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth poses at ``times`` by linear interpolation (heading unwrapped).

    Returns ``(poses (T, 3), valid (T,))``: a time is valid when it lies
    within the ground-truth span and the two samples around it are at most
    ``max_gap`` seconds apart (motion-capture dropouts are skipped, not
    bridged). Invalid rows hold NaN and must be masked by the caller.
    """
    if max_gap <= 0:
        raise ValueError(f"max_gap must be positive, got {max_gap!r}")
    gt = np.asarray(groundtruth, dtype=float)
    times = np.asarray(times, dtype=float)
    t = gt[:, 0]
    heading = np.unwrap(gt[:, 3])
    k = np.searchsorted(t, times, side="right")
    inside = (k > 0) & (k < len(t))
    kk = np.clip(k, 1, len(t) - 1)
    gap = t[kk] - t[kk - 1]
    exact = (k > 0) & (t[np.clip(k - 1, 0, len(t) - 1)] == times)
    valid = (inside & (gap <= max_gap)) | exact
    poses = np.full((len(times), 3), np.nan)
    if len(t) == 1:
        poses[valid] = gt[0, 1:4]
        return poses, valid
    frac = np.where(gap > 0, (times - t[kk - 1]) / np.where(gap > 0, gap, 1.0), 0.0)
    frac = np.clip(frac, 0.0, 1.0)
    x = gt[kk - 1, 1] + frac * (gt[kk, 1] - gt[kk - 1, 1])
    y = gt[kk - 1, 2] + frac * (gt[kk, 2] - gt[kk - 1, 2])
    h = heading[kk - 1] + frac * (heading[kk] - heading[kk - 1])
    stacked = np.stack([x, y, wrap_angle(h)], axis=-1)
    poses[valid] = stacked[valid]
    return poses, valid
