"""A sampling session's folder: ``session.toml`` (atomic), ``samples.csv`` and ``raw.csv`` (append-only).

Each capture appends its raw readings to ``raw.csv`` and then its averaged row to ``samples.csv``,
each as whole lines followed by ``fsync``: a SIGKILL or a power cut leaves at most one partial last
line, which :meth:`SessionFolder.open` cuts off (with any raw rows of a sample whose row never made
it), so a resumed session continues at the next sample id without duplicates. An append that fails
(disk full, file too large) takes back what it wrote of that capture and raises
:class:`errors.OutputError`: both files still end with a whole row, and the session continues with
``--resume`` once there is space. ``session.toml`` is rewritten atomically or not at all.

A reopened folder is validated before anything in it is repaired: ``session.toml``'s tables, the
plan, and every whole row of ``samples.csv`` and ``raw.csv`` (a problem names file, row, column),
each row against the embedded plan (a target it holds, the line that target is on, ids once). A
last row without its newline is kept when it is whole (every field, the last one as written);
only a torn one is dropped, and said.

One writer: a session that writes a folder holds an exclusive lock (``flock``) on its
``session.lock``, which holds the writer's process id, from before anything in it is read or
repaired to its end (the system releases it when the process ends, however). A second one is
refused: "folder in use by PID ...", nothing touched.

A sweep session (its plan has passes: ``station.acquire.sweep``) writes ``samples.csv`` with
``SWEEP_COLUMNS`` (the static columns and ``pass``; a target holds many rows, each of one pass),
appends each finished pass's rows at once, and keeps the rows it flagged (never samples) in
``flagged.csv`` with their reason.
"""

from __future__ import annotations

import csv
import fcntl
import io
import os
import re
import tempfile
import time
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
from station.formats.plan import Plan
from station.formats.samples import Q_COLUMNS
from station.formats.tables import RobotFile, SetupFile, load_robot, load_setup
from station.holders import named

SAMPLE_COLUMNS = (
    "sample", "target", "line", *Q_COLUMNS, "length_mm", "dial_mm", "t_s",
    "q_spread_deg", "length_spread_mm", "dial_spread_mm", "window_s", "t_wall_s",
)  # fmt: skip
SWEEP_COLUMNS = (
    "sample", "target", "line", "pass", *Q_COLUMNS, "length_mm", "dial_mm", "t_s",
    "q_spread_deg", "length_spread_mm", "dial_spread_mm", "window_s", "t_wall_s",
)  # fmt: skip
FLAGGED_COLUMNS = (
    "reason",
    "target",
    "line",
    "pass",
    *Q_COLUMNS,
    "length_mm",
    "dial_mm",
    "speed_mm_s",
    "t_s",
    "t_wall_s",
)
RAW_COLUMNS = (
    "sample", "k", "t_robot_s", *Q_COLUMNS, "qd_max_deg_s", "t_length_s", "length_mm", "t_dial_s", "dial_mm",
)  # fmt: skip


def sample_columns(header: dict) -> tuple[str, ...]:
    """The columns of a session's ``samples.csv``: a sweep plan's (rows with a pass) or the static."""
    plan = header.get("plan") or [{}]
    return SWEEP_COLUMNS if isinstance(plan[0], dict) and "pass" in plan[0] else SAMPLE_COLUMNS


class SessionHeader(BaseModel):
    """What ``session.toml`` holds that a resumed session uses; other keys are kept as they are.
    The station config (``station``) is validated by the caller, which knows its schema."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False, defer_build=True)

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


LAST_CELL = re.compile(r"-?\d+\.\d{6}")
"""The last column of both files as :func:`_cell` writes it (a float, 6 decimals): a last row that
ends so, with every field, is whole although its newline is missing."""


@dataclass
class _Rows:
    """A session CSV read back: its whole ``rows``, the bytes they take (``end``), and the last
    row's state: ``"kept"`` (whole, without its newline), ``"torn"`` (dropped) or None."""

    rows: list[dict]
    end: int
    tail: str | None = None
    torn: bytes = b""


def _whole_rows(path: Path, columns: tuple[str, ...]) -> _Rows:
    """The rows of a session CSV up to its last newline, and a last row after it if whole (a row
    torn by a crash is left out); InputError unless the header is ``columns``."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file (not a session folder?)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    keep = data.rfind(b"\n") + 1
    tail = _whole_tail(data[keep:], columns) if keep and data[keep:] else None
    try:
        reader = csv.reader(io.StringIO(data[:keep].decode()))
        header = next(reader, [])
        rows = list(reader) + ([tail] if tail else [])
    except (UnicodeDecodeError, csv.Error):
        raise InputError(f"{path}: not a session CSV file") from None
    if tuple(header) != columns:
        raise InputError(f"{path}: the header is not {','.join(columns)} (not written by station sample?)")
    for i, row in enumerate(rows):
        if len(row) != len(columns):
            raise InputError(
                f"{path}: row {i} (line {i + 2}): {len(row)} fields, the header has {len(columns)}"
            )
    found = _Rows([dict(zip(columns, row, strict=True)) for row in rows], keep)
    if keep < len(data):
        found.tail, found.torn = ("kept", b"") if tail else ("torn", data[keep:])
        found.end = len(data) if tail else keep
    return found


def _whole_tail(data: bytes, columns: tuple[str, ...]) -> list[str] | None:
    """The cells of a last row without its newline if it is whole, else None."""
    try:
        cells = next(csv.reader([data.decode()]), [])
    except (UnicodeDecodeError, csv.Error):
        return None
    return cells if len(cells) == len(columns) and LAST_CELL.fullmatch(cells[-1]) else None


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


LOCK_NAME = "session.lock"


class FolderLock:
    """The one-writer lock of a session folder: an exclusive ``flock`` on ``session.lock`` in it,
    which holds the writer's process id; released by :meth:`release` as often as it was taken,
    or by the end of the process. A process holds a folder's lock once: its openings share it."""

    _held: dict[tuple[int, int], FolderLock] = {}  # by the folder's (device, inode)

    def __init__(self, key: tuple[int, int], fh):
        self._key, self._fh, self._count = key, fh, 1

    @classmethod
    def take(cls, folder) -> FolderLock:
        """Lock ``folder`` (it exists) for this process; InputError naming the holder if another
        process has it, or saying why the lock file cannot be made."""
        folder = Path(folder)
        try:
            st = os.stat(folder)
            if (held := cls._held.get((st.st_dev, st.st_ino))) is not None:
                held._count += 1
                return held
            fh = open(folder / LOCK_NAME, "a+")  # noqa: SIM115 - held until release()
        except OSError as exc:
            raise InputError(f"{folder}: cannot write the session folder: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise InputError(f"{folder}: folder in use by {_holder(folder)}; nothing in it touched") from None
        fh.truncate(0)
        fh.write(f"{os.getpid()}\n")
        fh.flush()
        lock = cls._held[st.st_dev, st.st_ino] = cls((st.st_dev, st.st_ino), fh)
        return lock

    @staticmethod
    def check(folder) -> None:
        """InputError if another process holds ``folder``'s lock (without one: nothing done)."""
        if (Path(folder) / LOCK_NAME).exists():
            FolderLock.take(folder).release()

    def release(self) -> None:
        self._count -= 1
        if self._count == 0:
            del self._held[self._key]
            self._fh.close()


def _holder(folder: Path, tries: int = 10) -> str:
    """Who holds ``folder``'s lock: "PID n (command line)", read from the lock file (a writer
    that has just locked it may not have written its id yet: ``tries`` reads 50 ms apart)."""
    for _ in range(tries):
        try:
            return named(int((folder / LOCK_NAME).read_text().strip()))
        except (OSError, ValueError):
            time.sleep(0.05)
    return "another process"


def check_rows(rows: list[dict], plan: Plan, where: Path) -> None:
    """Every row (validated cells) names a target of the embedded ``plan`` and the line that
    target is on, each sample id and target once (a sweep plan's rows: the target's pass, and a
    target as often as it was swept past); InputError naming the row."""
    lines = dict(zip(plan.target.tolist(), plan.line.tolist(), strict=True))
    passes = (
        {}
        if plan.sweep_pass is None
        else dict(zip(plan.target.tolist(), plan.sweep_pass.tolist(), strict=True))
    )
    samples: dict[int, int] = {}
    targets: dict[int, int] = {}
    for i, row in enumerate(rows):
        sample, target, line = int(row["sample"]), int(row["target"]), int(row["line"])
        at = f"{where}: row {i} (line {i + 2})"
        if target not in lines:
            raise InputError(f"{at}: target {target} is not in the session's plan ({len(lines)} targets)")
        if line != lines[target]:
            raise InputError(f"{at}: line {line}, but target {target} is on line {lines[target]} in the plan")
        if sample in samples:
            raise InputError(f"{at}: sample id {sample} again (row {samples[sample]})")
        if passes and row.get("pass", "").strip() != str(passes[target]):
            raise InputError(
                f"{at}: pass {row.get('pass')}, but target {target} is in pass {passes[target]} in the plan"
            )
        if target in targets and not passes:
            raise InputError(f"{at}: target {target} measured again (row {targets[target]})")
        samples[sample], targets[target] = i, i


def check_session_rows(folder: Path) -> None:
    """Validate a session folder's ``samples.csv`` rows against its embedded plan (calibrate)."""
    folder = Path(folder)
    header = read_toml(folder / "session.toml")
    if "plan" not in header:  # a folder made without one (by hand) has nothing to check against
        return
    found = _whole_rows(folder / "samples.csv", sample_columns(header))
    _check_cells(folder / "samples.csv", found.rows, SAMPLE_CHECKS)
    check_rows(found.rows, _plan_of(header, folder), folder / "samples.csv")


def _plan_of(header: dict, folder: Path) -> Plan:
    return Plan.from_rows(header["plan"], str(folder / "session.toml"))


@dataclass
class SessionFolder:
    """An open session folder: its header (``session.toml`` content), the samples taken so far; a
    new one exists on disk only once :meth:`make` wrote it."""

    path: Path
    header: dict
    rows: list[dict] = field(default_factory=list)
    made: bool = True  # False from :meth:`new` until :meth:`make` wrote it
    lock: FolderLock | None = None  # held while this process writes the folder
    notes: list[str] = field(default_factory=list)  # what reopening repaired, for the session's log

    @property
    def samples_csv(self) -> Path:
        return self.path / "samples.csv"

    @property
    def raw_csv(self) -> Path:
        return self.path / "raw.csv"

    @property
    def flagged_csv(self) -> Path:
        return self.path / "flagged.csv"

    @property
    def columns(self) -> tuple[str, ...]:
        return sample_columns(self.header)

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
        FolderLock.check(path)  # a session running there: say so, rather than "resume it"
        _no_session_in(path)
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
        """Create the folder (and missing parents), lock it, and write the CSV headers and then
        ``session.toml`` (a folder without it is no session). Everything is written once here, so
        an unwritable or full disk fails before the first sample (InputError); so does a session
        that another process started there meanwhile."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write the session folder: {exc.strerror or exc}") from None
        self.lock = FolderLock.take(self.path)
        try:
            _no_session_in(self.path)
            files = [("samples.csv", self.columns), ("raw.csv", RAW_COLUMNS)]
            files += [("flagged.csv", FLAGGED_COLUMNS)] if self.columns == SWEEP_COLUMNS else []
            for name, columns in files:
                atomic_write(self.path / name, ",".join(columns) + "\n")
            atomic_write(self.path / "session.toml", toml_text(self.header))
        except OSError as exc:
            self.release()
            raise InputError(f"{self.path}: cannot write the session folder: {exc.strerror or exc}") from None
        except BaseException:
            self.release()
            raise
        self.made = True

    def release(self) -> None:
        """Let another process write the folder (the end of this process does it as well)."""
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    @classmethod
    def create(cls, path, header: dict) -> SessionFolder:
        """A new session at ``path``, checked and made at once (:meth:`new`, :meth:`make`)."""
        folder = cls.new(path, header)
        folder.make()
        return folder

    @staticmethod
    def lock_for_resume(path) -> FolderLock:
        """The lock of an existing session folder, taken before anything in it is read (a folder
        without ``session.toml`` fails as reading it does; one that cannot be written says so)."""
        path = Path(path)
        if not (path / "session.toml").is_file():
            read_toml(path / "session.toml")  # the one-line error of a missing or odd file
        if not os.access(path, os.W_OK):
            raise InputError(f"{path}: folder is not writable, cannot resume there")
        return FolderLock.take(path)

    @classmethod
    def open(cls, path, lock: FolderLock | None = None) -> SessionFolder:
        """An existing session, locked (``lock``: already taken by the caller), validated (its
        rows against its plan too), then repaired after a crash: a torn last line cut, a whole one
        without its newline completed, raw rows of a sample whose row never made it dropped.
        InputError names what is wrong; ``notes`` say what was repaired."""
        path = Path(path)
        lock = lock or cls.lock_for_resume(path)
        try:
            return cls._open(path, lock)
        except BaseException:
            lock.release()
            raise

    @classmethod
    def _open(cls, path: Path, lock: FolderLock) -> SessionFolder:
        header = read_toml(path / "session.toml")
        folder = cls(path, header, lock=lock)
        samples = _whole_rows(folder.samples_csv, folder.columns)
        _check_cells(folder.samples_csv, samples.rows, SAMPLE_CHECKS)
        if "plan" in header:  # resume_session has checked that it does
            check_rows(samples.rows, _plan_of(header, path), folder.samples_csv)
        folder.rows = samples.rows
        raw = _whole_rows(folder.raw_csv, RAW_COLUMNS)
        _check_cells(folder.raw_csv, raw.rows, RAW_CHECKS)
        for f, found in ((folder.samples_csv, samples), (folder.raw_csv, raw)):
            folder.notes += _repair_tail(f, found)
        keep = [r for r in raw.rows if int(r["sample"]) < folder.next_sample]
        if len(keep) != len(raw.rows):
            lines = [",".join(RAW_COLUMNS) + "\n"] + [_csv_line(RAW_COLUMNS, r) for r in keep]
            atomic_write(folder.raw_csv, "".join(lines))
        return folder

    def append_rows(self, rows: list[dict], flagged: list[dict]) -> None:
        """Store a sweep's pass at once: its ``flagged`` rows (``flagged.csv``), then its sample
        ``rows`` (each file's lines in one fsynced append); a failed write takes back what it wrote
        of both (:class:`errors.OutputError`)."""
        beside = (self.flagged_csv, [_csv_line(FLAGGED_COLUMNS, r) for r in flagged])
        self._store(
            beside, [_csv_line(self.columns, r) for r in rows], f"{len(rows)} rows of a sweep", "them"
        )
        self.rows += [{k: _cell(v) for k, v in row.items()} for row in rows]

    def keep_rows(self, keep) -> int:
        """Rewrite ``samples.csv`` (atomically) with only the rows for which ``keep(row)`` holds
        (a sweep's unfinished pass, cut on resume); the number of rows dropped."""
        kept = [r for r in self.rows if keep(r)]
        dropped = len(self.rows) - len(kept)
        if dropped:
            lines = [",".join(self.columns) + "\n"] + [_csv_line(self.columns, r) for r in kept]
            atomic_write(self.samples_csv, "".join(lines))
            self.rows = kept
        return dropped

    def append(self, row: dict, raw: list[dict]) -> None:
        """Store one capture: its raw readings, then its sample row (each fsynced). If either
        write fails, neither file keeps any of it (:class:`errors.OutputError`)."""
        beside = (self.raw_csv, [_csv_line(RAW_COLUMNS, r) for r in raw])
        self._store(beside, [_csv_line(SAMPLE_COLUMNS, row)], f"sample {row['sample']}", "it")
        self.rows.append({k: _cell(v) for k, v in row.items()})

    def _store(self, beside: tuple[Path, list[str]], lines: list[str], what: str, it: str) -> None:
        """Append ``beside`` (a file and its lines), then ``lines`` to ``samples.csv``; a failed
        write takes back what it wrote of both and raises :class:`errors.OutputError` about ``what``."""
        path, beside_lines = beside
        size = path.stat().st_size
        try:
            _append(path, beside_lines)
            try:
                _append(self.samples_csv, lines)
            except OSError:
                os.truncate(path, size)
                raise
        except OSError as exc:
            raise OutputError(
                f"{self.path}: cannot store {what} ({exc.strerror or exc}); the {len(self.rows)} samples "
                f"before {it} are kept: make room, then continue with --resume {self.path}"
            ) from None

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


def _no_session_in(path: Path) -> None:
    if (path / "session.toml").exists():
        raise InputError(f"{path}: already holds a session; continue it with --resume {path}")


def _repair_tail(path: Path, found: _Rows) -> list[str]:
    """Cut a torn last row, or end a whole one with its newline; a note saying which."""
    if found.tail == "kept":
        _append(path, ["\n"])
        return [f"{path}: its last row had no newline at the end; the row is whole and kept"]
    os.truncate(path, found.end)
    if found.tail == "torn":
        cut = found.torn.decode("utf-8", "replace")
        cut = cut if len(cut) <= 40 else cut[:37] + "..."
        return [f"{path}: a torn last row was dropped (a crash mid-write): {cut!r}"]
    return []


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


def measured_targets(folder: Path) -> set[int]:
    """The target ids a session folder's ``samples.csv`` holds a whole row for (read only: a
    running session may hold the folder)."""
    folder = check_session_folder(folder)
    found = _whole_rows(folder / "samples.csv", sample_columns(read_toml(folder / "session.toml")))
    _check_cells(folder / "samples.csv", found.rows, SAMPLE_CHECKS)
    return {int(r["target"]) for r in found.rows}


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
