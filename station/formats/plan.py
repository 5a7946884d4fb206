"""The plan: the configurations to measure, in order (contract: ``target,line,q1_deg..q6_deg``).

``station plan`` designs one; ``station sim serve`` publishes the plan its simulated robot walks
(``[sim] plan_csv``), which is where ``station sample`` looks when given no ``--plan``
(``[session] plan``).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errors import InputError
from station.formats.samples import Q_COLUMNS

PLAN_COLUMNS = ("target", "line", *Q_COLUMNS)


@dataclass(frozen=True)
class Plan:
    """Targets: ids (M,), gauge-line ids (M,) and joint configurations (M, 6) in degrees."""

    target: np.ndarray
    line: np.ndarray
    q_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.target)

    def csv_text(self) -> str:
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(PLAN_COLUMNS)
        for t, ln, q in zip(self.target, self.line, self.q_deg, strict=True):
            writer.writerow([int(t), int(ln), *(f"{v:.6f}" for v in q)])
        return out.getvalue()

    def rows(self) -> list[dict]:
        """As TOML-ready rows (embedded in ``session.toml``)."""
        return [
            {"target": int(t), "line": int(ln), "q_deg": [float(v) for v in q]}
            for t, ln, q in zip(self.target, self.line, self.q_deg, strict=True)
        ]

    @classmethod
    def of(cls, q_deg, line) -> Plan:
        """Targets numbered 0.. in order, from configurations (M, 6) [deg] and line ids (M,)."""
        q_deg = np.asarray(q_deg, float).reshape(-1, 6)
        return cls(np.arange(len(q_deg)), np.asarray(line, int), q_deg)

    @classmethod
    def from_rows(cls, rows: list[dict]) -> Plan:
        return cls(
            np.array([r["target"] for r in rows], int),
            np.array([r["line"] for r in rows], int),
            np.array([r["q_deg"] for r in rows], float).reshape(-1, 6),
        )


def load_plan(path) -> Plan:
    """Read a plan CSV; any problem is an ``InputError`` naming the file, row and column."""
    path = Path(path)
    try:
        rows = list(csv.DictReader(path.open(newline="")))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (IsADirectoryError, UnicodeDecodeError):
        raise InputError(f"{path}: not a plan CSV file") from None
    if not rows:
        raise InputError(f"{path}: no targets after the header row")
    missing = [c for c in PLAN_COLUMNS if c not in rows[0]]
    if missing:
        raise InputError(f"{path}: missing column {missing[0]}")
    values = np.empty((len(rows), len(PLAN_COLUMNS)))
    for i, row in enumerate(rows):
        for j, col in enumerate(PLAN_COLUMNS):
            try:
                values[i, j] = float(row[col])
            except (TypeError, ValueError):
                raise InputError(
                    f"{path}: row {i} (line {i + 2}): {col}: {row[col]!r} is not a number"
                ) from None
    target = values[:, 0].astype(int)
    if len(set(target)) != len(target):
        raise InputError(f"{path}: target ids must be unique")
    return Plan(target, values[:, 1].astype(int), values[:, 2:])
