"""A calibration history per robot: every ``station calibrate`` and ``station verify`` appends one
record to an embedded SQLite database (stdlib ``sqlite3``).

Where: ``--db``, else ``$STATION_HISTORY_DB``, else ``history.sqlite`` in the user's data folder
(``$XDG_DATA_HOME/calibration-station``, default ``~/.local/share/calibration-station``). Several
stations may write one database: SQLite's own locking (WAL journal, a busy timeout) serialises
them. A file that is not such a database, or a damaged one, is refused with one line naming it
(``PRAGMA integrity_check``) and is never written to: nothing already recorded is lost.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from errors import InputError
from station.formats.base import printable

ENV = "STATION_HISTORY_DB"
BUSY_TIMEOUT_MS = 30000
"""How long a writer waits for another station's write to finish before giving up."""
APPLICATION_ID = 0x53544E48  # "STNH": marks the file as this station's history
SCHEMA = """
CREATE TABLE IF NOT EXISTS records (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    robot TEXT NOT NULL,
    robot_name TEXT NOT NULL,
    time_utc TEXT NOT NULL,
    command TEXT NOT NULL,
    samples TEXT NOT NULL,
    table_path TEXT NOT NULL,
    table_hash TEXT NOT NULL,
    verdict TEXT,
    rmse_mm REAL,
    figures TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS records_robot ON records (robot, id);
"""
FLAG_SIGMAS = 3.0
"""A parameter that moved between consecutive calibrations by more than this many combined sigmas
is flagged."""


def database_path(flag: Path | None) -> Path:
    """``--db``, else ``$STATION_HISTORY_DB``, else the user's data folder's ``history.sqlite``."""
    if flag is not None:
        return flag
    if os.environ.get(ENV):
        return Path(os.environ[ENV])
    data = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(data) / "calibration-station" / "history.sqlite"


@dataclass(frozen=True)
class Record:
    """One command's record: the robot's identity (``serial``, else its name), when, which command
    on which samples with which table (path and SHA-256), the verdict, the RMSE [mm] and the
    command's figures (its report, JSON)."""

    robot: str
    robot_name: str
    time_utc: str
    command: str
    samples: str
    table_path: str
    table_hash: str
    verdict: str | None
    rmse_mm: float | None
    figures: dict

    @classmethod
    def of(cls, robot, command: str, samples: str, table: Path, figures: dict) -> Record:
        """The record of ``command`` on ``robot`` (a robot file: ``serial`` or ``name``)."""
        verdict = figures.get("verdict") or (figures.get("fit_check") or {}).get("verdict")
        rmse = figures.get("rmse_mm")
        if rmse is None:
            rmse = ((figures.get("after") or {}).get("train") or {}).get("rmse_mm")
        return cls(
            robot=robot.serial or robot.name,
            robot_name=robot.name,
            time_utc=datetime.now(timezone.utc).isoformat(timespec="seconds"),
            command=command,
            samples=printable(str(samples)),  # SQLite text is UTF-8: a name that is not, as \\xNN
            table_path=printable(str(table)),
            table_hash=file_hash(table),
            verdict=verdict,
            rmse_mm=rmse,
            figures=figures,
        )


def file_hash(path: Path) -> str:
    """SHA-256 of a file's bytes, hex; empty when it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return ""


def _connect(path: Path) -> sqlite3.Connection:
    """An open, checked history database, made (with its folder) where missing."""
    path = Path(path)
    if not path.exists():
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{path}: cannot create the history's folder ({exc.strerror})") from None
    try:
        conn = sqlite3.connect(path, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None)
    except sqlite3.Error as exc:
        raise InputError(f"{path}: cannot open the history database ({exc})") from None
    try:
        _check(conn, path)
    except BaseException:
        conn.close()
        raise
    return conn


def _check(conn: sqlite3.Connection, path: Path) -> None:
    """Refuse a file that is not a station history or is damaged; set up a new one."""
    try:
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        app = conn.execute("PRAGMA application_id").fetchone()[0]
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if app not in (0, APPLICATION_ID) or (app == 0 and tables):
            raise InputError(
                f"{path}: not a station history database (another program's SQLite file); "
                "point --db or $STATION_HISTORY_DB elsewhere"
            )
        ok = conn.execute("PRAGMA integrity_check").fetchone()[0]
        if ok != "ok":
            raise InputError(f"{path}: the history database is damaged ({ok}); {_damaged_hint(path)}")
        if app == 0:
            conn.execute("PRAGMA journal_mode = WAL")
            conn.executescript(f"BEGIN IMMEDIATE; {SCHEMA} PRAGMA application_id = {APPLICATION_ID}; COMMIT;")
    except sqlite3.DatabaseError as exc:
        raise InputError(f"{path}: not a readable history database ({exc}); {_damaged_hint(path)}") from None


def _damaged_hint(path: Path) -> str:
    return (
        f"nothing was written to it; keep it for recovery (sqlite3 {path.name} .recover) and point --db "
        "or $STATION_HISTORY_DB at a new file"
    )


def append(path: Path, record: Record) -> int:
    """Append ``record`` (one transaction); returns its id."""
    conn = _connect(path)
    try:
        cur = conn.execute(
            "INSERT INTO records (robot, robot_name, time_utc, command, samples, table_path, table_hash, "
            "verdict, rmse_mm, figures) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                record.robot,
                record.robot_name,
                record.time_utc,
                record.command,
                record.samples,
                record.table_path,
                record.table_hash,
                record.verdict,
                record.rmse_mm,
                json.dumps(record.figures),
            ),
        )
        return int(cur.lastrowid)
    except sqlite3.Error as exc:
        raise InputError(f"{path}: cannot append to the history ({exc})") from None
    finally:
        conn.close()


def robots(path: Path) -> list[dict]:
    """Every robot in the history: identity, name, records, calibrations, last time and verdict
    (none while no database exists)."""
    if not Path(path).exists():
        return []
    conn = _connect(path)
    try:
        rows = conn.execute(
            "SELECT robot, robot_name, COUNT(*), SUM(command = 'calibrate'), MAX(time_utc), "
            "(SELECT verdict FROM records r2 WHERE r2.robot = r.robot ORDER BY id DESC LIMIT 1) "
            "FROM records r GROUP BY robot ORDER BY robot"
        ).fetchall()
    finally:
        conn.close()
    keys = ("robot", "name", "records", "calibrations", "last_utc", "last_verdict")
    return [dict(zip(keys, row, strict=True)) for row in rows]


def records(path: Path, robot: str) -> list[dict]:
    """One robot's records, oldest first (figures parsed); none while no database exists."""
    if not Path(path).exists():
        return []
    conn = _connect(path)
    try:
        rows = conn.execute(
            "SELECT id, time_utc, command, samples, table_path, table_hash, verdict, rmse_mm, figures "
            "FROM records WHERE robot = ? ORDER BY id",
            (robot,),
        ).fetchall()
    finally:
        conn.close()
    keys = ("id", "time_utc", "command", "samples", "table", "table_hash", "verdict", "rmse_mm", "figures")
    out = [dict(zip(keys, row, strict=True)) for row in rows]
    for rec in out:
        rec["figures"] = json.loads(rec["figures"])
    return out


def moves(history: list[dict]) -> list[dict]:
    """Every parameter that moved between consecutive calibrations by more than ``FLAG_SIGMAS``
    combined sigmas (``sqrt(s1^2 + s2^2)``): param, change, sigmas, since (the earlier's time),
    at (the later's record id and time)."""
    calibrations = [r for r in history if r["command"] == "calibrate"]
    out = []
    for old, new in zip(calibrations[:-1], calibrations[1:], strict=True):
        before, after = old["figures"].get("parameters", {}), new["figures"].get("parameters", {})
        for name in after:
            if name not in before:
                continue
            change = after[name]["value"] - before[name]["value"]
            sigma = (after[name]["sigma"] ** 2 + before[name]["sigma"] ** 2) ** 0.5
            if sigma > 0 and abs(change) > FLAG_SIGMAS * sigma:
                out.append(
                    {
                        "param": name,
                        "change": change,
                        "sigmas": abs(change) / sigma,
                        "since": old["time_utc"],
                        "record": new["id"],
                        "time_utc": new["time_utc"],
                    }
                )
    return out
