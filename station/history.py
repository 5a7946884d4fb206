"""A calibration history per robot: every ``station calibrate`` and ``station verify`` appends one
record to an embedded SQLite database (stdlib ``sqlite3``).

Where: ``--db``, else ``$STATION_HISTORY_DB``, else ``history.sqlite`` in the user's data folder
(``$XDG_DATA_HOME/calibration-station``, default ``~/.local/share/calibration-station``). Several
stations may write one database: SQLite's own locking (WAL journal, a busy timeout) serialises
them, and a new file is checked and set up in one locked transaction. Reading opens it read-only
(also in a folder this user cannot write). A file that is not such a database, of a newer
``SCHEMA_VERSION`` or another layout, a damaged one (``PRAGMA integrity_check``) or a record this
station would not write is refused with one line naming it and is never written to: nothing
already recorded is lost.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sqlite3
import stat
import time
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
SCHEMA_VERSION = 1
"""The layout above (``PRAGMA user_version``; 0: a history made before the version was written,
the same layout, stamped 1 at its next append). A newer one is refused, never written to."""
COLUMNS = (
    "id", "robot", "robot_name", "time_utc", "command", "samples", "table_path", "table_hash", "verdict",
    "rmse_mm", "figures",
)  # fmt: skip
TYPES = {key: str for key in COLUMNS} | {"id": int, "verdict": str | None, "rmse_mm": int | float | None}
"""What each column holds as this station writes it (SQLite keeps any value in any column)."""
UNKNOWN = "another program's record or a hand's; nothing was changed"
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


def _exists(path: Path) -> bool:
    """Whether the file ``path`` is there; InputError where it cannot be told (a folder this user
    may not search, a parent that is a file) or it is a folder."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return False
    except OSError as exc:
        raise InputError(f"{path}: cannot reach the history database ({exc.strerror})") from None
    if stat.S_ISDIR(mode):
        raise InputError(
            f"{path}: a folder; --db names the history's file (e.g. {Path(path) / 'history.sqlite'})"
        )
    return True


def _connect(path: Path) -> sqlite3.Connection:
    """The history opened to append to, made (with its folder) where missing: checked, and set up
    when new, in one locked transaction (stations that make it at the same instant wait their turn)."""
    path = Path(path)
    if not _exists(path):
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError(f"{path}: cannot create the history's folder ({exc.strerror})") from None
    conn = _open(path, "rwc")
    try:
        with _refusing_errors(path):
            conn.execute("BEGIN IMMEDIATE")
            version = _check(conn, path)
            if version is None:
                _create(conn)
            elif version < SCHEMA_VERSION:
                conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
            conn.execute("COMMIT")
            _wal(conn)
    except BaseException:
        conn.close()
        raise
    return conn


def _open(path: Path, mode: str, immutable: bool = False) -> sqlite3.Connection:
    """A connection in SQLite ``mode`` (``ro``: read only, ``rwc``: made where missing)."""
    uri = f"{Path(path).absolute().as_uri()}?mode={mode}" + ("&immutable=1" if immutable else "")
    try:
        return sqlite3.connect(uri, uri=True, timeout=BUSY_TIMEOUT_MS / 1000, isolation_level=None)
    except sqlite3.Error as exc:
        raise InputError(f"{path}: cannot open the history database ({exc})") from None


@contextlib.contextmanager
def _refusing_errors(path: Path):
    """SQLite's errors as one line naming ``path``: a file SQLite cannot take as damaged (with
    how to recover it), one it cannot use here (locked, read-only, out of space) as such."""
    try:
        yield
    except sqlite3.OperationalError as exc:
        raise InputError(
            f"{path}: cannot use the history database ({exc}); nothing was written to it"
        ) from None
    except sqlite3.DatabaseError as exc:
        raise InputError(f"{path}: not a readable history database ({exc}); {_damaged_hint(path)}") from None


def _check(conn: sqlite3.Connection, path: Path) -> int | None:
    """The history's schema version (None for a new, empty file); InputError for a file that is
    not a station history of a version and layout this station knows, or that is damaged."""
    app = conn.execute("PRAGMA application_id").fetchone()[0]
    version = conn.execute("PRAGMA user_version").fetchone()[0]
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if app == 0 and not tables and version == 0:
        return None
    if app != APPLICATION_ID:
        raise InputError(
            f"{path}: not a station history database (another program's SQLite file); "
            "point --db or $STATION_HISTORY_DB elsewhere"
        )
    if version > SCHEMA_VERSION:
        raise InputError(
            f"{path}: a history of schema version {version}, written by a newer station (this one "
            f"knows version {SCHEMA_VERSION}); nothing was written to it; update the station, or point "
            "--db elsewhere"
        )
    ok = conn.execute("PRAGMA integrity_check").fetchone()[0]
    if ok != "ok":
        raise InputError(f"{path}: the history database is damaged ({ok}); {_damaged_hint(path)}")
    _check_layout(conn, path, tables)
    return version


def _check_layout(conn: sqlite3.Connection, path: Path, tables: set[str]) -> None:
    """Refuse a history whose ``records`` table is missing or lacks a column."""
    found = {r[1] for r in conn.execute("PRAGMA table_info(records)")} if "records" in tables else set()
    missing = [c for c in COLUMNS if c not in found]
    if missing:
        what = "no table records" if not found else "table records lacks " + ", ".join(missing)
        raise InputError(
            f"{path}: not a history layout this station knows ({what}); nothing was written to it; "
            "point --db or $STATION_HISTORY_DB at a new file"
        )


def _create(conn: sqlite3.Connection) -> None:
    """Set up a new history (inside the caller's transaction)."""
    for statement in SCHEMA.split(";"):
        if statement.strip():
            conn.execute(statement)
    conn.execute(f"PRAGMA application_id = {APPLICATION_ID}")
    conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")


def _wal(conn: sqlite3.Connection) -> None:
    """Switch to the WAL journal (once per file: it stays); another station switching it at the
    same instant is waited for."""
    deadline = time.monotonic() + BUSY_TIMEOUT_MS / 1000
    while conn.execute("PRAGMA journal_mode").fetchone()[0] != "wal":
        try:
            conn.execute("PRAGMA journal_mode = WAL")
        except sqlite3.OperationalError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.01)


def _reader(path: Path) -> sqlite3.Connection | None:
    """The history opened read-only and checked; None while there is none (or it is empty)."""
    path = Path(path)
    if not _exists(path):
        return None
    conn = _open(path, "ro")
    try:
        with _refusing_errors(path):
            try:
                conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
            except sqlite3.OperationalError:
                conn.close()
                conn = _read_only_folder(path)
            version = _check(conn, path)
    except BaseException:
        conn.close()
        raise
    if version is None:
        conn.close()
        return None
    return conn


def _read_only_folder(path: Path) -> sqlite3.Connection:
    """A WAL history in a folder this user cannot write (SQLite cannot make its ``-shm`` file):
    read as it lies on disk (``immutable``) unless its ``-wal`` holds records not yet in it."""
    wal = Path(f"{path}-wal")
    if _exists(wal) and wal.stat().st_size > 0:
        raise InputError(
            f"{path}: cannot be read in a folder this user cannot write: its write-ahead log "
            f"({wal.name}) holds records not yet in the file; copy the files to a folder of yours"
        )
    return _open(path, "ro", immutable=True)


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
            f"INSERT INTO records ({', '.join(COLUMNS[1:])}) VALUES ({', '.join('?' * (len(COLUMNS) - 1))})",
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
        raise InputError(f"{path}: cannot append to the history ({exc}); nothing was written to it") from None
    finally:
        conn.close()


def robots(path: Path) -> list[dict]:
    """Every robot in the history: identity, name, records, calibrations, last time and verdict
    (none while no database exists)."""
    conn = _reader(path)
    if conn is None:
        return []
    try:
        rows = conn.execute(ROBOTS).fetchall()
        states = {row[0]: _state(conn, row[0]) if row[3] == 0 else row[6] for row in rows}
    finally:
        conn.close()
    columns = ("robot", "robot_name", "records", "calibrations", "time_utc", "verdict")
    keys = ("robot", "name", "records", "calibrations", "last_utc", "last_verdict")
    for row in rows:
        _check_row(
            dict(zip(columns, row[:6], strict=True)) | {"verdict": states[row[0]]},
            f"{path}: robot {row[0]!r}",
        )
    return [dict(zip(keys, row[:6], strict=True)) | {"state": states[row[0]]} for row in rows]


ROBOTS = (
    "SELECT robot, robot_name, COUNT(*), SUM(command = 'calibrate'), MAX(time_utc), "
    "(SELECT verdict FROM records r2 WHERE r2.robot = r.robot ORDER BY id DESC LIMIT 1), "
    "(SELECT verdict FROM records r2 WHERE r2.robot = r.robot AND r2.table_hash = ("
    "SELECT table_hash FROM records r3 WHERE r3.robot = r.robot AND r3.command = 'calibrate' "
    "ORDER BY id DESC LIMIT 1) ORDER BY id DESC LIMIT 1) "
    "FROM records r GROUP BY robot ORDER BY robot"
)
"""Per robot: identity, name, records, calibrations, last time, last verdict and its state: the
latest verdict on its current table (the latest calibration's, by SHA-256)."""


def _state(conn: sqlite3.Connection, robot: str) -> str | None:
    """The state of a robot without a calibration in the history: the latest verdict on a table that
    is not a nominal one (``table_kind`` of its figures; a record made before it counts)."""
    rows = conn.execute("SELECT verdict, figures FROM records WHERE robot = ? ORDER BY id DESC", (robot,))
    for verdict, figures in rows:
        if _table_kind(figures) != "nominal":
            return verdict
    return None


def _table_kind(figures: str) -> str | None:
    """A stored report's ``table_kind`` (``corrected``, ``nominal``); None where it has none."""
    try:
        kind = json.loads(figures).get("table_kind")
    except (TypeError, ValueError, AttributeError):
        return None
    return kind if isinstance(kind, str) else None


def records(path: Path, robot: str) -> list[dict]:
    """One robot's records, oldest first (figures parsed); none while no database exists."""
    conn = _reader(path)
    if conn is None:
        return []
    try:
        rows = conn.execute(f"SELECT {', '.join(COLUMNS)} FROM records WHERE robot = ? ORDER BY id", (robot,))
        return judged([_record(dict(zip(COLUMNS, row, strict=True)), path) for row in rows])
    finally:
        conn.close()


def judged(found: list[dict]) -> list[dict]:
    """Each record of one robot (oldest first) with the table it judged (``judged``, a phrase) and
    whether that is the robot's current table (``current``): the latest calibration's (by SHA-256);
    without a calibration here, any table but a nominal one. Only such records set its state."""
    written = {r["table_hash"]: r for r in found if r["command"] == "calibrate" and r["table_hash"]}
    latest = next((r["table_hash"] for r in reversed(found) if r["command"] == "calibrate"), None)
    out = []
    for r in found:
        kind = r["figures"].get("table_kind")
        current = r["table_hash"] == latest if latest is not None else kind != "nominal"
        out.append(r | {"judged": _judged_table(r, written.get(r["table_hash"]), kind), "current": current})
    return out


def _judged_table(record: dict, calibration: dict | None, kind) -> str:
    """The table ``record`` judged: ``the table it wrote`` (a calibration), ``the table of
    calibration #3 (2026-...)``, ``a nominal table``, ``a corrected table calibrated 2026-...
    elsewhere`` or, for a record made before tables were told apart, ``a table not calibrated in
    this history``."""
    if calibration is record:
        return "the table it wrote"
    if calibration is not None:
        return f"the table of calibration #{calibration['id']} ({calibration['time_utc']})"
    if kind == "nominal":
        return "a nominal table"
    when = record["figures"].get("table_calibrated_utc")
    if kind == "corrected" and isinstance(when, str):
        return f"a corrected table calibrated {when} elsewhere"
    return "a table not calibrated in this history"


def _record(row: dict, path: Path) -> dict:
    """A stored row as a record (figures parsed); InputError naming it where a value is not what
    this station writes (another program's or a hand's)."""
    where = f"{path}: record #{row['id']}"
    _check_row(row, where)
    try:
        datetime.fromisoformat(row["time_utc"])
    except ValueError:
        raise InputError(
            f"{where}: its time_utc {row['time_utc']!r:.40} is not an ISO 8601 time; {UNKNOWN}"
        ) from None
    try:
        figures = json.loads(row["figures"])
    except ValueError as exc:  # json.JSONDecodeError is one
        raise InputError(f"{where}: its figures are not JSON ({exc}); {UNKNOWN}") from None
    if not isinstance(figures, dict) or not _parameters_ok(figures.get("parameters", {})):
        raise InputError(f"{where}: its figures are not a report this station writes; {UNKNOWN}")
    rec = {
        ("table" if k == "table_path" else k): v for k, v in row.items() if k not in ("robot", "robot_name")
    }
    return rec | {"figures": figures}


def _check_row(row: dict, where: str) -> None:
    """InputError naming the first value of ``row`` not of the type this station writes."""
    for key, value in row.items():
        if key in TYPES and not isinstance(value, TYPES[key]):
            raise InputError(
                f"{where}: its {key} is {type(value).__name__}, not as the station writes it; {UNKNOWN}"
            )


def _parameters_ok(parameters) -> bool:
    """A report's ``parameters``: name -> {"value": number, "sigma": number, ...}."""
    return isinstance(parameters, dict) and all(
        isinstance(p, dict) and all(isinstance(p.get(k), int | float) for k in ("value", "sigma"))
        for p in parameters.values()
    )


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
