"""A sampling session's folder: ``session.toml`` (atomic), ``samples.csv`` and ``raw.csv`` (append-only).

Each capture appends its raw readings to ``raw.csv`` and then its averaged row to ``samples.csv``,
each as one ``write`` of whole lines followed by ``fsync``: a SIGKILL or a power cut leaves at most
one partial last line, which :meth:`SessionFolder.open` cuts off (with any raw rows of a sample
whose row never made it), so a resumed session continues at the next sample id without duplicates.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path

from errors import InputError
from station.formats.base import atomic_write, read_toml, toml_text, validate
from station.formats.samples import Q_COLUMNS
from station.formats.tables import RobotFile, SetupFile, load_robot, load_setup

SAMPLE_COLUMNS = (
    "sample", "target", "line", *Q_COLUMNS, "length_mm", "dial_mm", "t_s",
    "q_spread_deg", "length_spread_mm", "dial_spread_mm", "window_s", "t_wall_s",
)  # fmt: skip
RAW_COLUMNS = (
    "sample", "k", "t_robot_s", *Q_COLUMNS, "qd_max_deg_s", "t_length_s", "length_mm", "t_dial_s", "dial_mm",
)  # fmt: skip


def _append(path: Path, lines: list[str]) -> None:
    """Append whole lines with one write, then fsync: nothing half-written survives a crash."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, "".join(lines).encode())
        os.fsync(fd)
    finally:
        os.close(fd)


def _csv_line(columns, row: dict) -> str:
    return ",".join(_cell(row.get(c, "")) for c in columns) + "\n"


def _cell(v) -> str:
    return f"{v:.6f}" if isinstance(v, float) else str(v)


def _cut_torn_tail(path: Path) -> None:
    """Truncate ``path`` after its last newline (a row cut by a crash is dropped)."""
    data = path.read_bytes()
    keep = data.rfind(b"\n") + 1
    if keep != len(data):
        with path.open("r+b") as fh:
            fh.truncate(keep)


@dataclass
class SessionFolder:
    """An open session folder: its header (``session.toml`` content), the samples taken so far."""

    path: Path
    header: dict
    rows: list[dict] = field(default_factory=list)

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
    def create(cls, path, header: dict) -> SessionFolder:
        """A new session at ``path`` (created; must not hold a session yet). Everything is written
        once here, so an unwritable or full disk fails before the first sample (InputError)."""
        path = Path(path)
        if (path / "session.toml").exists():
            raise InputError(f"{path}: already holds a session; continue it with --resume {path}")
        try:
            path.mkdir(parents=True, exist_ok=True)
            atomic_write(path / "session.toml", toml_text(header))
            for name, columns in (("samples.csv", SAMPLE_COLUMNS), ("raw.csv", RAW_COLUMNS)):
                atomic_write(path / name, ",".join(columns) + "\n")
        except OSError as exc:
            raise InputError(f"{path}: cannot write the session folder: {exc.strerror or exc}") from None
        return cls(path, header)

    @classmethod
    def open(cls, path) -> SessionFolder:
        """An existing session, repaired after a crash: torn last lines cut, orphan raw rows dropped."""
        path = Path(path)
        header = read_toml(path / "session.toml")
        folder = cls(path, header)
        if not os.access(path, os.W_OK):
            raise InputError(f"{path}: folder is not writable, cannot resume there")
        for f in (folder.samples_csv, folder.raw_csv):
            if not f.exists():
                raise InputError(f"{f}: no such file (not a session folder?)")
            _cut_torn_tail(f)
        with folder.samples_csv.open(newline="") as fh:
            folder.rows = list(csv.DictReader(fh))
        folder._drop_orphan_raw()
        return folder

    def _drop_orphan_raw(self) -> None:
        with self.raw_csv.open(newline="") as fh:
            raw = list(csv.DictReader(fh))
        keep = [r for r in raw if int(r["sample"]) < self.next_sample]
        if len(keep) != len(raw):
            atomic_write(
                self.raw_csv,
                "".join([",".join(RAW_COLUMNS) + "\n"] + [_csv_line(RAW_COLUMNS, r) for r in keep]),
            )

    def append(self, row: dict, raw: list[dict]) -> None:
        """Store one capture: its raw readings, then its sample row (each fsynced)."""
        _append(self.raw_csv, [_csv_line(RAW_COLUMNS, r) for r in raw])
        _append(self.samples_csv, [_csv_line(SAMPLE_COLUMNS, row)])
        self.rows.append({k: _cell(v) for k, v in row.items()})

    def update_header(self, **changes) -> None:
        self.header.update(changes)
        atomic_write(self.path / "session.toml", toml_text(self.header))


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
