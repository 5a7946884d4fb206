"""The contract's files: robot tables, setups, sample CSVs and session folders, validated at load.

Every problem becomes an ``InputError`` whose one line names the file, the row or key, and what is
wrong. Values stay in the contract's units (mm, degrees); conversion to radians happens in
``station.calibration``.
"""

from __future__ import annotations

import csv
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from station.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Joint(_Strict):
    alpha_deg: float
    a_mm: float
    d_mm: float
    theta_deg: float
    q_min_deg: float = -180.0
    q_max_deg: float = 180.0
    sigma: dict[str, float] | None = None  # written by a calibration: per-parameter sigma


class RobotFile(_Strict):
    """A robot model (contract: robot model TOML); a corrected table adds ``calibration``."""

    name: str
    convention: Literal["dh"] = "dh"
    tool_mm: Vec3 = [0.0, 0.0, 0.0]
    joints: Annotated[list[Joint], Field(min_length=6, max_length=6)]
    calibration: dict | None = None

    def table_deg(self) -> np.ndarray:
        """(6, 4) table in display units, columns theta_deg, d_mm, a_mm, alpha_deg."""
        return np.array([[j.theta_deg, j.d_mm, j.a_mm, j.alpha_deg] for j in self.joints])

    def limits_deg(self) -> np.ndarray:
        return np.array([[j.q_min_deg, j.q_max_deg] for j in self.joints])


class Drawstring(_Strict):
    anchor_mm: Vec3
    length_offset_mm: float
    sigma_mm: float = Field(0.02, gt=0)


class Dial(_Strict):
    axis: Vec3 | None = None
    sigma_mm: float = Field(0.002, gt=0)


class LineSetup(_Strict):
    """One gauge-block placement; ``point_mm``, ``direction`` (base frame), usable ``length_mm`` and
    the tool ``approach`` direction are needed only to plan measurements (``station plan``)."""

    id: int
    dial_axis: Vec3 | None = None
    point_mm: Vec3 | None = None
    direction: Vec3 | None = None
    length_mm: float = Field(400.0, gt=0)
    approach: Vec3 | None = None


class SetupFile(_Strict):
    """Station geometry as measured roughly (contract: setup TOML). ``line_sigma_mm``: how well the
    tool sits on the gauge edge (joint-reading noise at the TCP included); ``rho``: line-term weight."""

    drawstring: Drawstring | None = None
    dial: Dial | None = None
    lines: list[LineSetup] = []
    line_sigma_mm: float = Field(0.01, gt=0)
    rho: float = Field(1.0, gt=0)


def read_toml(path: Path) -> dict:
    """Parse a TOML file; a missing or malformed file is an InputError naming it."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: not valid TOML: {exc}") from None


def validate(schema: type[BaseModel], data: dict, where: str):
    """``schema.model_validate(data)`` with the first error as one line naming ``where`` and the key."""
    try:
        return schema.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(p) for p in err["loc"]) or "(top level)"
        if err["type"] in ("too_short", "too_long") and key.endswith("joints"):
            raise InputError(f"{where}: joints: expected 6 joints, got {len(err['input'])}") from None
        if err["type"] in ("too_short", "too_long"):
            raise InputError(f"{where}: {key}: expected 3 numbers, got {len(err['input'])}") from None
        raise InputError(f"{where}: {key}: {err['msg']}") from None


def load_robot(path) -> RobotFile:
    return validate(RobotFile, read_toml(path), str(path))


def load_setup(path) -> SetupFile:
    return validate(SetupFile, read_toml(path), str(path))


# -- samples ---------------------------------------------------------------------------------------
Q_COLUMNS = tuple(f"q{i}_deg" for i in range(1, 7))
XYZ_COLUMNS = ("x_mm", "y_mm", "z_mm")


@dataclass(frozen=True)
class Samples:
    """A validated sample set: ``kind`` "drawstring" or "position", joints (N, 6) [deg], the
    measurement (N,) length or (N, 3) position [mm], dial (N,) [mm] (NaN: none), line (N,) ids
    (-1: no line constraint)."""

    path: str
    kind: str
    q_deg: np.ndarray
    measured: np.ndarray
    dial_mm: np.ndarray
    line: np.ndarray

    def __len__(self) -> int:
        return self.q_deg.shape[0]


def load_samples(path) -> Samples:
    """Read a contract sample CSV (columns in any order, unknown columns ignored)."""
    path = Path(path)
    try:
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a CSV file") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file") from None
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise InputError(f"{path}: empty file, expected a header row and samples")
    header = [h.strip() for h in rows[0]]
    kind = _kind(path, header)
    missing = [c for c in Q_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: missing column {missing[0]}")
    if len(rows) == 1:
        raise InputError(f"{path}: no samples after the header row")
    col = {name: header.index(name) for name in header}
    body = rows[1:]
    q = _numbers(path, body, [col[c] for c in Q_COLUMNS], Q_COLUMNS)
    if kind == "drawstring":
        measured = _numbers(path, body, [col["length_mm"]], ["length_mm"])[:, 0]
    else:
        measured = _numbers(path, body, [col[c] for c in XYZ_COLUMNS], XYZ_COLUMNS)
    dial = (
        _numbers(path, body, [col["dial_mm"]], ["dial_mm"], allow_empty=True)[:, 0]
        if "dial_mm" in col
        else None
    )
    line = _line_ids(path, body, col.get("line"))
    n = len(body)
    return Samples(str(path), kind, q, measured, np.full(n, np.nan) if dial is None else dial, line)


def _kind(path: Path, header: list[str]) -> str:
    has_len = "length_mm" in header
    has_xyz = any(c in header for c in XYZ_COLUMNS)
    if has_len and has_xyz:
        raise InputError(f"{path}: has both length_mm and x_mm/y_mm/z_mm: a set is drawstring or position")
    if not has_len and not has_xyz:
        raise InputError(f"{path}: has neither length_mm nor x_mm,y_mm,z_mm: nothing measured")
    if has_xyz and not all(c in header for c in XYZ_COLUMNS):
        missing = next(c for c in XYZ_COLUMNS if c not in header)
        raise InputError(f"{path}: missing column {missing}")
    return "drawstring" if has_len else "position"


def _numbers(path, body, cols, names, allow_empty=False) -> np.ndarray:
    out = np.empty((len(body), len(cols)))
    for i, row in enumerate(body):
        for j, (c, name) in enumerate(zip(cols, names, strict=True)):
            cell = row[c].strip() if c < len(row) else ""
            if cell == "" and allow_empty:
                out[i, j] = math.nan
                continue
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
                cell = cell or "(empty)"
            if not math.isfinite(value):
                raise InputError(f"{path}: row {i} (line {i + 2}): {name}: {cell!r} is not a finite number")
            out[i, j] = value
    return out


def _line_ids(path, body, c) -> np.ndarray:
    if c is None:
        return np.zeros(len(body), int)
    ids = np.empty(len(body), int)
    for i, row in enumerate(body):
        cell = row[c].strip() if c < len(row) else ""
        if cell == "":
            ids[i] = -1
            continue
        try:
            ids[i] = int(float(cell))
            if ids[i] < 0 or ids[i] != float(cell):
                raise ValueError
        except ValueError:
            raise InputError(
                f"{path}: row {i} (line {i + 2}): line: {cell!r} is not a line id (a whole number >= 0)"
            ) from None
    return ids


# -- sessions and outputs --------------------------------------------------------------------------
def load_robot_and_setup(session: Path | None, robot: Path | None, setup: Path | None):
    """Robot table, setup, the setup's name for messages and the session's samples path: from a
    ``session`` folder's ``session.toml`` if given, the ``robot``/``setup`` files overriding it;
    None where neither."""
    robot_file = setup_file = samples = None
    where = str(setup)
    if session is not None:
        robot_file, setup_file, samples = load_session(session)
        where = f"{Path(session) / 'session.toml'} [setup]"
    if robot:
        robot_file = load_robot(robot)
    if setup:
        setup_file, where = load_setup(setup), str(setup)
    return robot_file, setup_file, where, samples


def load_session(folder: Path) -> tuple[RobotFile, SetupFile, Path]:
    """Robot table, setup and samples path embedded in a session folder's ``session.toml``."""
    folder = Path(folder)
    where = folder / "session.toml"
    data = read_toml(where)
    for key in ("robot", "setup"):
        if key not in data:
            raise InputError(f"{where}: missing table [{key}]")
    robot = validate(RobotFile, data["robot"], f"{where} [robot]")
    setup = validate(SetupFile, data["setup"], f"{where} [setup]")
    return robot, setup, folder / "samples.csv"


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes it 0600; results are for others to read
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def check_writable(path: Path, what: str) -> Path:
    """Fail early (InputError) if ``path`` cannot be written: missing or read-only folder."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{what} {path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise InputError(f"{what} {path}: folder {folder} is not writable")
    if path.is_dir():
        raise InputError(f"{what} {path}: is a directory")
    return path


def toml_text(data: dict) -> str:
    return tomli_w.dumps(data)
