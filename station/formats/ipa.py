"""Reader for the IPA robot-accuracy dataset (Landgraf et al., CASE 2021; MIT licence).

A series is a ``;``-separated CSV with decimal commas and a header row. Used columns: the joint
readings ``shoulder_pan_joint`` ... ``wrist_3_joint`` [rad] and the tracker's measurement of the
T-Mac probe ``measurement_x/y/z`` [mm, tracker frame], and ``measurement_temperature`` [deg C] where
the file has it; the rest (goal poses in m / rad, rotations in degrees, standard deviations, time
stamps) is not needed for positions. Beside it,
``Trafo_TM_F_init.txt`` holds the initial T-Mac-to-flange transform, a 4x4 matrix [mm], whose
inverse's translation is the probe point in the flange frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errors import InputError
from station.formats.base import MAX_JOINT_DEG, MAX_LENGTH_MM, number_cell

JOINT_COLUMNS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
POSITION_COLUMNS = ("measurement_x", "measurement_y", "measurement_z")
TEMPERATURE_COLUMN = "measurement_temperature"
PROBE_FILE = "Trafo_TM_F_init.txt"


@dataclass(frozen=True)
class IpaSeries:
    """One measured series: joint readings ``q_rad`` (N, 6), probe positions ``position_mm``
    (N, 3) in the tracker frame and the ambient ``temperature_c`` (N,) [deg C] (NaN where the file
    has no such column), read from ``path``."""

    path: Path
    q_rad: np.ndarray
    position_mm: np.ndarray
    temperature_c: np.ndarray

    def __len__(self) -> int:
        return self.q_rad.shape[0]


def read_series(path) -> IpaSeries:
    """Read a series CSV. Raises InputError naming the file, row or column on bad input."""
    path = Path(path)
    lines = _read_lines(path)
    if not lines:
        raise InputError(f"{path}: empty file, expected a ';'-separated header row")
    header = [h.strip() for h in lines[0].split(";")]
    missing = [c for c in JOINT_COLUMNS + POSITION_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: missing column {missing[0]!r} (not an IPA series file?)")
    names = JOINT_COLUMNS + POSITION_COLUMNS + ((TEMPERATURE_COLUMN,) if TEMPERATURE_COLUMN in header else ())
    cols = [header.index(c) for c in names]
    rows = [_parse_row(path, k, line, len(header), cols, names) for k, line in enumerate(lines[1:], start=2)]
    if not rows:
        raise InputError(f"{path}: no data rows after the header")
    values = np.array(rows)
    temperature = values[:, 9] if values.shape[1] > 9 else np.full(len(values), np.nan)
    return IpaSeries(path, values[:, :6], values[:, 6:9], temperature)


def read_probe_mm(path) -> np.ndarray:
    """Probe point in the flange frame [mm] (3,) from a ``Trafo_TM_F_init*.txt`` 4x4 matrix that
    gives the flange in the T-Mac frame: the point is ``-R^T t``."""
    path = Path(path)
    text = _read_lines(path)
    try:
        matrix = np.array([[float(v) for v in line.split()] for line in text if line.strip()])
    except ValueError as exc:
        raise InputError(f"{path}: not a matrix of numbers ({exc})") from None
    if matrix.shape != (4, 4):
        raise InputError(f"{path}: expected a 4x4 matrix, got shape {matrix.shape}")
    if not np.all(np.abs(matrix) <= MAX_LENGTH_MM):
        raise InputError(
            f"{path}: every entry must be a finite number within -{MAX_LENGTH_MM:g} .. {MAX_LENGTH_MM:g}"
        )
    rot, t = matrix[:3, :3], matrix[:3, 3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4):
        raise InputError(f"{path}: the upper-left 3x3 block is not a rotation")
    return -rot.T @ t


def probe_file_for(series_path) -> Path:
    """The initial probe transform beside a series file."""
    return Path(series_path).parent / PROBE_FILE


def _read_lines(path: Path) -> list[str]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc.__class__.__name__}: {exc})") from None
    return [line for line in text.splitlines() if line.strip()]


MAX_JOINT_RAD = float(np.radians(MAX_JOINT_DEG))
POSITION_LIMIT = (MAX_LENGTH_MM, "mm")
LIMITS = {**dict.fromkeys(JOINT_COLUMNS, (MAX_JOINT_RAD, "rad")), TEMPERATURE_COLUMN: (200.0, "deg C")}
"""Range and unit of each column's numbers (the probe's positions: POSITION_LIMIT)."""


def _parse_row(path: Path, lineno: int, line: str, n_fields: int, cols: list[int], names) -> list[float]:
    """The columns ``names`` (at ``cols``) of one line: finite, within the station's ranges."""
    fields = line.split(";")
    if len(fields) != n_fields:
        raise InputError(f"{path}: line {lineno}: {len(fields)} fields, the header has {n_fields}")
    out = []
    for name, c in zip(names, cols, strict=True):
        try:
            out.append(number_cell(fields[c].strip().replace(",", "."), *LIMITS.get(name, POSITION_LIMIT)))
        except ValueError as exc:
            raise InputError(f"{path}: line {lineno}, column {name!r}: {exc}") from None
    return out
