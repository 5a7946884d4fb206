"""``station report`` behind the command line: what a calibration certificate states, gathered from
a calibration report (REPORT.json) or a verification report (V.json), the setup it names and the
robot's history. Only what these carry is stated; what none of them carries is said to be unknown.
The page itself is ``station.view.certificate``'s."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from errors import InputError
from station.formats.base import read_toml, validate

CALIBRATION, VERIFICATION = "calibration", "verification"
SESSION_SETUP = " [setup]"
"""How a report names the setup a session folder embeds: ``DIR/session.toml [setup]``."""


class _Open(BaseModel):
    """A report's keys the certificate reads; any others are kept and ignored."""

    model_config = ConfigDict(extra="allow", defer_build=True)


class Metrics(_Open):
    rmse_mm: float
    mean_mm: float
    max_mm: float


class Fit(_Open):
    train: Metrics
    holdout: Metrics | None = None


class Workspace(_Open):
    predicted_rmse_mm: float
    predicted_rmse_95_mm: float | None = None


class Parameter(_Open):
    value: float
    sigma: float
    nominal: float | None = None
    delta: float | None = None


class Robot(_Open):
    name: str
    serial: str | None = None
    convention: str | None = None


class CalibrationFile(_Open):
    """REPORT.json (``docs/report.md``) as far as the certificate reads it."""

    kind: str
    method: str
    before: Fit
    after: Fit
    parameters: dict[str, Parameter]
    workspace: Workspace
    held: list[dict] = []
    warnings: list[str] = []
    lines: list[dict] = []
    terms: dict[str, Parameter] = {}
    robot: Robot | None = None
    samples: str | None = None
    setup: str | None = None
    created_utc: str | None = None
    station_version: str | None = None
    fit_check: dict | None = None
    holdout_scope: str = "none"
    next: str = ""


class VerificationFile(_Open):
    """V.json (``station verify --report``) as far as the certificate reads it."""

    verdict: str
    rmse_mm: float
    mean_mm: float
    max_mm: float
    noise_ratio: float
    lines: list[dict]
    kind: str = "drawstring"
    meaning: str = ""
    expected_ratio: float | None = None
    likely: list[dict] = []
    rows: int | None = None
    table: str | None = None
    table_kind: str | None = None
    table_calibrated_utc: str | None = None
    robot: Robot | None = None
    samples: str | None = None
    setup: str | None = None
    created_utc: str | None = None
    station_version: str | None = None
    next: str = ""


@dataclass(frozen=True)
class Instrument:
    """One instrument of the cell: ``name``, how the station reached it (``device``; None: not
    stated, empty: no device) and its stated noise as the setup gives it (``noise``, words; None:
    unknown; ``sigma_mm``, a reading's, where it has one)."""

    name: str
    device: str | None
    noise: str | None
    sigma_mm: float | None = None


@dataclass(frozen=True)
class Certificate:
    """What the page states: the report (``kind``: calibration or verification, ``data``: its
    validated keys, ``path``), the robot's ``convention`` (None: unknown), the ``instruments``
    (empty: ``instruments_note`` says why), the ``samples_rows`` counted in the samples file (None:
    not known) and the robot's ``history`` (its records, oldest first, and the flagged ``moved``)
    in the database at ``db``."""

    kind: str
    data: CalibrationFile | VerificationFile
    path: str
    convention: str | None
    instruments: tuple[Instrument, ...]
    instruments_note: str
    samples_rows: int | None
    db: str
    history: tuple[dict, ...]
    moved: tuple[dict, ...]

    @property
    def robot_id(self) -> str | None:
        """The robot's identity in the history: its serial, else its name (None: not stated)."""
        robot = self.data.robot
        return None if robot is None else robot.serial or robot.name


def load_report(path: Path) -> tuple[str, CalibrationFile | VerificationFile]:
    """The report at ``path`` and its kind, told apart by its keys (a verdict: V.json); InputError
    naming the file for one that is missing, not JSON, or neither report."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file (a report of station calibrate or station verify)") from None
    except IsADirectoryError:
        raise InputError(f"{path}: a folder, expected a report JSON (station calibrate --report)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a report: not JSON ({exc})") from None
    if not isinstance(data, dict) or not ({"verdict", "parameters"} & data.keys()):
        raise InputError(
            f"{path}: not a report of station calibrate (no parameters) or station verify (no verdict)"
        )
    if "verdict" in data:
        return VERIFICATION, validate(VerificationFile, data, f"{path} (a verification report)")
    return CALIBRATION, validate(CalibrationFile, data, f"{path} (a calibration report)")


def gather(path: Path, db: Path) -> Certificate:
    """Everything the certificate of the report at ``path`` states; ``db``: the history database."""
    from station import history

    kind, data = load_report(path)
    setup_file, session = _setup_source(data.setup)
    instruments, note = instruments_of(data.kind, setup_file, session)
    robot = data.robot
    records = history.records(db, robot.serial or robot.name) if robot else []
    return Certificate(
        kind=kind,
        data=data,
        path=str(path),
        convention=(robot.convention if robot else None) or _session_convention(setup_file, session),
        instruments=instruments,
        instruments_note=note,
        samples_rows=getattr(data, "rows", None) or count_rows(data.samples),
        db=str(db),
        history=tuple(records),
        moved=tuple(history.moves(records)),
    )


def _setup_source(setup: str | None) -> tuple[Path | None, bool]:
    """The file a report's ``setup`` names and whether it is a session folder's ``session.toml``."""
    if not setup:
        return None, False
    session = setup.endswith(SESSION_SETUP) or Path(setup).name == "session.toml"
    return Path(setup.removesuffix(SESSION_SETUP)), session


def instruments_of(kind: str, setup: Path | None, session: bool) -> tuple[tuple[Instrument, ...], str]:
    """The instruments and their stated noise from the setup a report names (the station's devices
    too where it is a session's), and a note saying where they come from or why they are unknown."""
    if kind == "position":
        return (Instrument("position instrument (laser tracker)", None, None),), (
            "a position set: the report states no noise for its instrument"
        )
    if setup is None or not setup.is_file():
        where = "names no setup" if setup is None else f"names its setup '{setup}', which is no file here"
        return (), f"unknown: the report {where}; the instruments' stated noise cannot be given"
    try:
        raw = read_toml(setup)
    except InputError as exc:
        return (), f"unknown: the setup the report names cannot be read now ({exc})"
    table = raw.get("setup", {}) if session else raw
    station = raw.get("station", {}) if session else {}
    return _instruments(table, station), f"as stated in {setup}{SESSION_SETUP if session else ''}"


DEFAULT_NOISE = {"drawstring": 0.02, "dial": 0.002, "line": 0.01, "contact": 0.2}
"""The setup's defaults where a key is left out (``station.formats.tables.SetupFile``)."""


def _instruments(setup: dict, station: dict) -> tuple[Instrument, ...]:
    """The drawstring, the dial (where the setup has each) and the gauge edge's contact."""
    out = []
    for key, name in (("drawstring", "drawstring displacement sensor"), ("dial", "dial indicator")):
        if isinstance(setup.get(key), dict):
            sigma, text = _noise(setup[key].get("sigma_mm"), DEFAULT_NOISE[key], "per reading")
            out.append(Instrument(name, _device(station.get(key)), text, sigma))
    line = _noise(setup.get("line_sigma_mm"), DEFAULT_NOISE["line"], "on the edge")[1]
    contact = _noise(setup.get("contact_sigma_mm"), DEFAULT_NOISE["contact"], "off it without a dial")[1]
    out.append(Instrument("gauge-block edge (tool contact)", "", f"{line}; {contact}"))
    return tuple(out)


def _noise(value, default: float, what: str) -> tuple[float, str]:
    """A stated noise [mm] (the setup's default where it gives none) and how the page says it."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value), f"{value:g} mm {what}"
    return default, f"{default:g} mm {what} (the default)"


def _device(section) -> str | None:
    """How a session reached a device (``modbus_tcp 127.0.0.1:5020``, ``serial /dev/ttyUSB0``)."""
    if not isinstance(section, dict):
        return None
    kind = section.get("kind") or ("serial" if "port" in section else None)
    where = section.get("host") and f"{section['host']}:{section.get('port', '')}".rstrip(":")
    where = where or section.get("port") or section.get("url")
    dialect = section.get("dialect")
    parts = [str(p) for p in (kind, where, dialect and f"({dialect})") if p]
    return " ".join(parts) or None


def _session_convention(setup: Path | None, session: bool) -> str | None:
    """For a report made before it carried ``robot.convention``: the convention of the robot the
    session folder it names embeds (a robot file without the key is ``dh``); None: unknown."""
    if not (session and setup is not None and setup.is_file()):
        return None
    robot = read_toml(setup).get("robot")
    return robot.get("convention", "dh") if isinstance(robot, dict) else None


def count_rows(samples: str | None) -> int | None:
    """The data rows of the samples CSV a report names, counted now (None: not here, not text)."""
    if not samples:
        return None
    try:
        with open(samples, encoding="utf-8") as fh:
            return max(sum(1 for line in fh if line.strip()) - 1, 0)
    except (OSError, UnicodeDecodeError):
        return None
