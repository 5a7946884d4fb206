"""The contract's sample CSVs (drawstring or position sets), validated at load: a problem is an
``InputError`` naming the file, the row and the column."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errors import InputError
from station.formats.base import (
    MAX_DIAL_MM,
    MAX_ID,
    MAX_JOINT_DEG,
    MAX_LENGTH_MM,
    folder_kind,
    id_cell,
    number_cell,
)
from station.formats.units import check_joints_in_degrees

Q_COLUMNS = tuple(f"q{i}_deg" for i in range(1, 7))
XYZ_COLUMNS = ("x_mm", "y_mm", "z_mm")
MAX_SESSION_S = 1e9  # a row's time since its session began: decades


@dataclass(frozen=True)
class Samples:
    """A validated sample set: ``kind`` "drawstring" or "position", joints (N, 6) [deg], the
    measurement (N,) length or (N, 3) position [mm], dial (N,) [mm] (NaN: none), line (N,) ids
    (-1: no line constraint); a sweep's rows (columns ``pass`` and ``t_s``) their pass (N,) ids (-1:
    none) and time (N,) [s], which say which rows share their errors (``calib.serial``)."""

    path: str
    kind: str
    q_deg: np.ndarray
    measured: np.ndarray
    dial_mm: np.ndarray
    line: np.ndarray
    sweep_pass: np.ndarray | None = None
    t_s: np.ndarray | None = None

    def __len__(self) -> int:
        return self.q_deg.shape[0]


def load_samples(path) -> Samples:
    """Read a contract sample CSV (columns in any order, unknown columns ignored).

    A file of numbers only is read whole by numpy's C parser (a million rows in 2.1 CPU s; Python's
    ``csv`` and ``float`` took 9.4); any other (an empty cell, a quoted one, a word, a
    ragged row, a number out of range) is read cell by cell, so that its error names the cell."""
    path = Path(path)
    plain = _plain_table(path)
    if plain is not None:
        try:
            return _samples(path, plain[0], _Table(plain[1]))
        except _NotPlain:
            pass
    header, body = read_csv(path, "samples")
    return _samples(path, header, _Cells(path, body))


def _samples(path: Path, header: list[str], cells) -> Samples:
    """The sample set of a file's ``header`` and its ``cells`` (``_Table`` or ``_Cells``)."""
    kind = _kind(path, header)
    missing = [c for c in Q_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: missing column {missing[0]}")
    if not cells.rows:
        raise InputError(f"{path}: no samples after the header row")
    col = {name: header.index(name) for name in header}
    q = cells.numbers([col[c] for c in Q_COLUMNS], Q_COLUMNS)
    if kind == "drawstring":
        measured = cells.numbers([col["length_mm"]], ["length_mm"])[:, 0]
    else:
        measured = cells.numbers([col[c] for c in XYZ_COLUMNS], XYZ_COLUMNS)
    dial = cells.numbers([col["dial_mm"]], ["dial_mm"], allow_empty=True)[:, 0] if "dial_mm" in col else None
    line = np.zeros(cells.rows, int) if "line" not in col else cells.ids(col["line"], "line", "a line id")
    check_joints_in_degrees(str(path), q, "rows")
    swept = "pass" in col and "t_s" in col
    return Samples(
        str(path),
        kind,
        q,
        measured,
        np.full(cells.rows, np.nan) if dial is None else dial,
        line,
        cells.ids(col["pass"], "pass", "a pass id") if swept else None,
        cells.numbers([col["t_s"]], ["t_s"])[:, 0] if swept else None,
    )


class _NotPlain(Exception):
    """A cell of a ``_Table`` fails its column's check: the file is read again cell by cell."""


def _plain_table(path: Path) -> tuple[list[str], np.ndarray] | None:
    """The header and every cell of a CSV file of numbers only (N, columns) [float]; None where
    it is not one (a missing or unreadable file, an empty, quoted or word cell, a ragged row)."""
    try:
        with path.open(newline="") as fh:
            header = next(csv.reader(fh), None)
            if not header or not any(h.strip() for h in header):
                return None
            table = np.loadtxt(fh, delimiter=",", comments=None, ndmin=2, quotechar=None)
    except (OSError, ValueError, csv.Error):  # UnicodeDecodeError is a ValueError
        return None
    if table.shape[1] != len(header) or not table.shape[0]:
        return None
    return [h.strip() for h in header], table


class _Table:
    """``_Cells`` of a ``_plain_table``: the same checks on whole columns, ``_NotPlain`` where one
    fails."""

    def __init__(self, table: np.ndarray):
        self.table, self.rows = table, table.shape[0]

    def numbers(self, cols, names, allow_empty=False) -> np.ndarray:
        out = self.table[:, cols]
        limit = np.array([_LIMITS.get(name, (MAX_LENGTH_MM, "mm"))[0] for name in names])
        if not np.all(np.isfinite(out) & (np.abs(out) <= limit)):
            raise _NotPlain
        return out

    def ids(self, c: int, name: str, what: str) -> np.ndarray:
        out = self.table[:, c]
        if not np.all((out >= 0) & (out <= MAX_ID) & (out == np.round(out))):
            raise _NotPlain
        return out.astype(int)


class _Cells:
    """The rows of a CSV file as text, each column checked as it is read: ``numbers`` (N, len(cols))
    and ``ids`` (N,), an ``InputError`` naming the first bad cell."""

    def __init__(self, path: Path, body: list[list[str]]):
        self.path, self.body, self.rows = path, body, len(body)

    def numbers(self, cols, names, allow_empty=False) -> np.ndarray:
        return parse_numbers(self.path, self.body, cols, names, allow_empty)

    def ids(self, c: int, name: str, what: str) -> np.ndarray:
        return _ids(self.path, self.body, c, name, what)


def read_csv(path: Path, what: str) -> tuple[list[str], list[list[str]]]:
    """The header (stripped names) and the non-blank rows of a CSV file of ``what``."""
    try:
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{path}: {folder_kind(path)}, expected a CSV file") from None
    except (UnicodeDecodeError, csv.Error):
        raise InputError(f"{path}: not a text CSV file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    rows = [r for r in rows if any(cell.strip() for cell in r)]
    if not rows:
        raise InputError(f"{path}: empty file, expected a header row and {what}")
    return [h.strip() for h in rows[0]], rows[1:]


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


_LIMITS = {
    **dict.fromkeys(Q_COLUMNS, (MAX_JOINT_DEG, "deg")),
    "dial_mm": (MAX_DIAL_MM, "mm"),
    "t_s": (MAX_SESSION_S, "s"),
}
"""Range and unit of a column's numbers (the others are lengths)."""


def parse_numbers(path, body, cols, names, allow_empty=False) -> np.ndarray:
    """(N, len(cols)) numbers from columns ``cols`` (named ``names``) of the rows ``body``: joints
    within MAX_JOINT_DEG, the dial within MAX_DIAL_MM, lengths within MAX_LENGTH_MM (an empty cell is
    NaN where ``allow_empty``); a bad cell is an InputError naming the file, the row and the column.

    Each column is read whole (Python's ``float`` on every cell, the limits checked on the array);
    only a file with a bad cell is read again cell by cell, to name the first."""
    try:
        return np.stack(
            [
                _column(body, c, *_LIMITS.get(name, (MAX_LENGTH_MM, "mm")), allow_empty)
                for c, name in zip(cols, names, strict=True)
            ],
            axis=1,
        )
    except ValueError:
        return _parse_cells(path, body, cols, names, allow_empty)


def _column(body, c: int, limit: float, unit: str, allow_empty: bool) -> np.ndarray:
    """Column ``c`` of ``body`` as numbers (N,), NaN for an empty cell where ``allow_empty``;
    ValueError where a cell is no finite number within ``-limit .. limit``."""
    cells = [row[c] if c < len(row) else "" for row in body]
    empty = np.zeros(len(cells), bool)
    if allow_empty:
        empty = np.fromiter((not s.strip() for s in cells), bool, len(cells))
        cells = ["nan" if e else s for s, e in zip(cells, empty, strict=True)]
    values = np.fromiter(map(float, cells), float, len(cells))
    if not np.all(empty | (np.isfinite(values) & (np.abs(values) <= limit))):
        raise ValueError(f"a cell is no finite number within -{limit:g} .. {limit:g} {unit}")
    return values


def _parse_cells(path, body, cols, names, allow_empty) -> np.ndarray:
    """``parse_numbers`` cell by cell, row by row: the InputError of the first bad cell."""
    out = np.empty((len(body), len(cols)))
    for i, row in enumerate(body):
        for j, (c, name) in enumerate(zip(cols, names, strict=True)):
            cell = row[c].strip() if c < len(row) else ""
            if cell == "" and allow_empty:
                out[i, j] = math.nan
                continue
            try:
                out[i, j] = number_cell(cell, *_LIMITS.get(name, (MAX_LENGTH_MM, "mm")))
            except ValueError as exc:
                raise InputError(f"{path}: row {i} (line {i + 2}): {name}: {exc}") from None
    return out


def _ids(path, body, c: int, name: str, what: str) -> np.ndarray:
    """Column ``c`` (``name``) of ``body`` as ids (N,), -1 for an empty cell."""
    ids = np.empty(len(body), int)
    for i, row in enumerate(body):
        cell = row[c].strip() if c < len(row) else ""
        try:
            ids[i] = -1 if cell == "" else id_cell(cell, what)
        except ValueError as exc:
            raise InputError(f"{path}: row {i} (line {i + 2}): {name}: {exc}") from None
    return ids
