"""A sampling session's folder: ``session.toml`` (atomic), ``samples.csv`` and ``raw.csv`` (append-only).

Each capture appends its raw readings to ``raw.csv`` and then its averaged row to ``samples.csv``,
each as whole lines followed by ``fsync``: a SIGKILL or a power cut leaves at most one partial last
line, which :meth:`SessionFolder.open` cuts off (with any raw rows of a sample whose row never made
it), so a resumed session continues at the next sample id without duplicates. An append that fails
(disk full, file too large) takes back what it wrote of that capture and raises
:class:`errors.OutputError`: both files still end with a whole row, and the session continues with
``--resume`` once there is space. ``session.toml`` is rewritten atomically or not at all.

A reopened folder is validated before anything in it is repaired: ``session.toml``'s tables, the
plan, and every whole row of ``samples.csv`` and ``raw.csv`` (a problem names file, row, column).
"""

from __future__ import annotations

import csv
import io
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

from errors import InputError, OutputError
from station.formats.base import (
    MAX_DIAL_MM,
    MAX_JOINT_DEG,
    MAX_LENGTH_MM,
    atomic_write,
    id_cell,
    number_cell,
    read_toml,
    toml_text,
    validate,
)
from station.formats.samples import Q_COLUMNS
from station.formats.tables import RobotFile, SetupFile, load_robot, load_setup

SAMPLE_COLUMNS = (
    "sample", "target", "line", *Q_COLUMNS, "length_mm", "dial_mm", "t_s",
    "q_spread_deg", "length_spread_mm", "dial_spread_mm", "window_s", "t_wall_s",
)  # fmt: skip
RAW_COLUMNS = (
    "sample", "k", "t_robot_s", *Q_COLUMNS, "qd_max_deg_s", "t_length_s", "length_mm", "t_dial_s", "dial_mm",
)  # fmt: skip


class SessionHeader(BaseModel):
    """What ``session.toml`` holds that a resumed session uses; other keys are kept as they are.
    The station config (``station``) is validated by the caller, which knows its schema."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)

    start_wall_s: Annotated[float, Field(ge=0)]
    robot: RobotFile
    setup: SetupFile
    station: dict
    plan: list


def _append(path: Path, lines: list[str]) -> None:
    """Append whole lines, then fsync: nothing half-written survives a crash. A write that fails
    part way (disk full, file size limit) is taken back before the error is raised."""
    data = "".join(lines).encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        size = os.fstat(fd).st_size
        try:
            written = 0
            while written < len(data):  # a short write (the size limit reached) leaves the rest
                written += os.write(fd, data[written:])
            os.fsync(fd)
        except OSError:
            os.ftruncate(fd, size)
            raise
    finally:
        os.close(fd)


def _csv_line(columns, row: dict) -> str:
    return ",".join(_cell(row.get(c, "")) for c in columns) + "\n"


def _cell(v) -> str:
    return f"{v:.6f}" if isinstance(v, float) else str(v)


def _whole_rows(path: Path, columns: tuple[str, ...]) -> tuple[list[dict], int]:
    """The rows of a session CSV up to its last newline (a row torn by a crash is left out), and
    the length in bytes they take; InputError unless the header is ``columns``."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file (not a session folder?)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    keep = data.rfind(b"\n") + 1
    try:
        reader = csv.reader(io.StringIO(data[:keep].decode()))
        header = next(reader, [])
        rows = list(reader)
    except (UnicodeDecodeError, csv.Error):
        raise InputError(f"{path}: not a session CSV file") from None
    if tuple(header) != columns:
        raise InputError(f"{path}: the header is not {','.join(columns)} (not written by station sample?)")
    for i, row in enumerate(rows):
        if len(row) != len(columns):
            raise InputError(
                f"{path}: row {i} (line {i + 2}): {len(row)} fields, the header has {len(columns)}"
            )
    return [dict(zip(columns, row, strict=True)) for row in rows], keep


def _check_cells(path: Path, rows: list[dict], checks: dict) -> None:
    """Each column named in ``checks`` holds what its check accepts (a ValueError says why not);
    ids are rewritten as plain whole numbers (``1e5`` -> ``100000``)."""
    for i, row in enumerate(rows):
        for column, check in checks.items():
            try:
                value = check(row[column].strip())
            except ValueError as exc:
                raise InputError(f"{path}: row {i} (line {i + 2}): {column}: {exc}") from None
            if isinstance(value, int):
                row[column] = str(value)


def _time(cell: str) -> float:
    return number_cell(cell, 1e12, "s")


def _joint(cell: str) -> float:
    return number_cell(cell, MAX_JOINT_DEG, "deg")


def _length(cell: str) -> float:
    return number_cell(cell, MAX_LENGTH_MM, "mm")


def _optional_dial(cell: str) -> float | None:
    return None if cell == "" else number_cell(cell, MAX_DIAL_MM, "mm")


SAMPLE_CHECKS = {
    "sample": lambda c: id_cell(c, "a sample id"),
    "target": lambda c: id_cell(c, "a target id"),
    "line": lambda c: id_cell(c, "a line id"),
    **dict.fromkeys(Q_COLUMNS, _joint),
    "length_mm": _length,
    "dial_mm": _optional_dial,
    "t_s": _time,
}
"""What a resumed session reads of ``samples.csv`` (the live view replays these columns)."""
RAW_CHECKS = {"sample": lambda c: id_cell(c, "a sample id")}


@dataclass
class SessionFolder:
    """An open session folder: its header (``session.toml`` content), the samples taken so far; a
    new one exists on disk only once :meth:`make` wrote it."""

    path: Path
    header: dict
    rows: list[dict] = field(default_factory=list)
    made: bool = True  # False from :meth:`new` until :meth:`make` wrote it

    @property
    def samples_csv(self) -> Path:
        return self.path / "samples.csv"

    @property
    def raw_csv(self) -> Path:
        return self.path / "raw.csv"

    @property
    def rrd(self) -> Path:
        return self.path / "session.rrd"

    @property
    def finished_targets(self) -> set[int]:
        return {int(r["target"]) for r in self.rows}

    @property
    def next_sample(self) -> int:
        return max((int(r["sample"]) for r in self.rows), default=-1) + 1

    @classmethod
    def new(cls, path, header: dict) -> SessionFolder:
        """A session to be made at ``path`` by :meth:`make`: checked now and nothing written (no
        session there yet, a folder the station can create and write), so that bad input fails
        before any device is opened and a session that never starts leaves nothing behind."""
        path = Path(path)
        if (path / "session.toml").exists():
            raise InputError(f"{path}: already holds a session; continue it with --resume {path}")
        existing = next(p for p in (path.absolute(), *path.absolute().parents) if p.exists())
        if not existing.is_dir():
            raise InputError(f"{path}: cannot write the session folder: {existing} is not a folder")
        try:  # what make() does first, undone: permissions alone miss a read-only file system
            os.rmdir(tempfile.mkdtemp(dir=existing, prefix=".station-probe-"))
        except OSError as exc:
            raise InputError(
                f"{path}: cannot write the session folder in {existing}: {exc.strerror}"
            ) from None
        return cls(path, header, made=False)

    def make(self) -> None:
        """Create the folder (and missing parents) with ``session.toml`` and the CSV headers.
        Everything is written once here, so an unwritable or full disk fails before the first
        sample (InputError)."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            atomic_write(self.path / "session.toml", toml_text(self.header))
            for name, columns in (("samples.csv", SAMPLE_COLUMNS), ("raw.csv", RAW_COLUMNS)):
                atomic_write(self.path / name, ",".join(columns) + "\n")
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write the session folder: {exc.strerror or exc}") from None
        self.made = True

    @classmethod
    def create(cls, path, header: dict) -> SessionFolder:
        """A new session at ``path``, checked and made at once (:meth:`new`, :meth:`make`)."""
        folder = cls.new(path, header)
        folder.make()
        return folder

    @classmethod
    def open(cls, path) -> SessionFolder:
        """An existing session, validated, then repaired after a crash: torn last lines cut, raw
        rows of a sample whose row never made it dropped. InputError names what is wrong."""
        path = Path(path)
        header = read_toml(path / "session.toml")
        folder = cls(path, header)
        if not os.access(path, os.W_OK):
            raise InputError(f"{path}: folder is not writable, cannot resume there")
        folder.rows, samples_end = _whole_rows(folder.samples_csv, SAMPLE_COLUMNS)
        _check_cells(folder.samples_csv, folder.rows, SAMPLE_CHECKS)
        raw, raw_end = _whole_rows(folder.raw_csv, RAW_COLUMNS)
        _check_cells(folder.raw_csv, raw, RAW_CHECKS)
        for f, end in ((folder.samples_csv, samples_end), (folder.raw_csv, raw_end)):
            os.truncate(f, end)
        keep = [r for r in raw if int(r["sample"]) < folder.next_sample]
        if len(keep) != len(raw):
            lines = [",".join(RAW_COLUMNS) + "\n"] + [_csv_line(RAW_COLUMNS, r) for r in keep]
            atomic_write(folder.raw_csv, "".join(lines))
        return folder

    def append(self, row: dict, raw: list[dict]) -> None:
        """Store one capture: its raw readings, then its sample row (each fsynced). If either
        write fails, neither file keeps any of it (:class:`errors.OutputError`)."""
        raw_size = self.raw_csv.stat().st_size
        try:
            _append(self.raw_csv, [_csv_line(RAW_COLUMNS, r) for r in raw])
            try:
                _append(self.samples_csv, [_csv_line(SAMPLE_COLUMNS, row)])
            except OSError:
                os.truncate(self.raw_csv, raw_size)
                raise
        except OSError as exc:
            raise OutputError(
                f"{self.path}: cannot store sample {row['sample']} ({exc.strerror or exc}); the "
                f"{len(self.rows)} samples before it are kept: make room, then continue with "
                f"--resume {self.path}"
            ) from None
        self.rows.append({k: _cell(v) for k, v in row.items()})

    def update_header(self, **changes) -> None:
        """Rewrite ``session.toml`` with ``changes`` (atomically: on failure the old file stays); a
        folder not made yet takes them into what :meth:`make` writes."""
        header = {**self.header, **changes}
        if not self.made:
            self.header = header
            return
        try:
            atomic_write(self.path / "session.toml", toml_text(header))
        except OSError as exc:
            raise OutputError(
                f"{self.path / 'session.toml'}: cannot update ({exc.strerror or exc}); the previous "
                f"one is kept, with the {len(self.rows)} samples in {self.samples_csv}"
            ) from None
        self.header = header


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


def replaced_by(session: Path, given: dict[str, tuple[Path, RobotFile | SetupFile]]) -> tuple[str, ...]:
    """What flags replace of the robot and setup a ``session`` folder embeds: ``given`` maps a flag
    (``--robot``, ``--setup``) to its file and what it holds; one note per file that differs,
    naming the first difference (``--robot R replaces the robot embedded in S/session.toml: name
    'HSR-JR680' -> 'UR10'``)."""
    robot, setup, _ = load_session(session)
    embedded = {"--robot": ("robot", robot), "--setup": ("setup", setup)}
    where, notes = Path(session) / "session.toml", []
    for flag, (path, new) in given.items():
        what, old = embedded[flag]
        difference = first_difference(old.model_dump(), new.model_dump())
        if difference:
            notes.append(f"{flag} {path} replaces the {what} embedded in {where}: {difference}")
    return tuple(notes)


def first_difference(a, b, key: str = "") -> str | None:
    """Where two plain values (dicts, lists, numbers, text) first differ, as ``key old -> new``
    (``joints.1.a_mm 900.0 -> 612.0``); None where they are equal."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = [*a, *(k for k in b if k not in a)]
        pairs = [(a.get(k), b.get(k), f"{key}.{k}" if key else str(k)) for k in keys]
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        pairs = [(x, y, f"{key}.{i}") for i, (x, y) in enumerate(zip(a, b, strict=True))]
    else:
        return None if a == b else f"{key} {a!r} -> {b!r}"
    return next((d for x, y, k in pairs if (d := first_difference(x, y, k))), None)


def check_session_folder(folder: Path) -> Path:
    """Bad input naming what ``folder`` is unless it is a session folder (holds ``session.toml``)."""
    folder = Path(folder)
    if not folder.exists():
        raise InputError(f"{folder}: no such file or folder")
    if not folder.is_dir():
        raise InputError(f"{folder}: a file, expected a session folder (station sample --out DIR)")
    if not (folder / "session.toml").is_file():
        raise InputError(f"{folder}: a folder without session.toml, not a session folder")
    return folder


def samples_path(path: Path) -> Path:
    """The samples CSV that ``path`` names: the file itself, or a session folder's samples.csv."""
    path = Path(path)
    return check_session_folder(path) / "samples.csv" if path.is_dir() else path


def load_session(folder: Path) -> tuple[RobotFile, SetupFile, Path]:
    """Robot table, setup and samples path embedded in a session folder's ``session.toml``."""
    folder = check_session_folder(folder)
    where = folder / "session.toml"
    data = read_toml(where)
    for key in ("robot", "setup"):
        if key not in data:
            raise InputError(f"{where}: missing table [{key}]")
    robot = validate(RobotFile, data["robot"], f"{where} [robot]")
    setup = validate(SetupFile, data["setup"], f"{where} [setup]")
    return robot, setup, folder / "samples.csv"


def session_header(folder: SessionFolder) -> SessionHeader:
    """The validated ``session.toml`` of an opened folder (InputError naming the key)."""
    return validate(SessionHeader, folder.header, str(folder.path / "session.toml"))
