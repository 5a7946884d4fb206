"""A robot program as joint targets (contract: ``station compensate``): CSV with ``q1_deg..q6_deg``
per row, other columns kept as they are; the compensated program is the same rows with the joints
replaced and ``shift_mm`` and ``status`` added."""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from errors import InputError
from station.formats.samples import Q_COLUMNS, parse_numbers, read_csv
from station.formats.units import check_joints_in_degrees

ADDED_COLUMNS = ("shift_mm", "status")


@dataclass(frozen=True)
class Program:
    """A validated program: its ``header`` and ``rows`` (cells as read, each as long as the header)
    and the joint targets ``q_deg`` (N, 6)."""

    path: str
    header: list[str]
    rows: list[list[str]]
    q_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.rows)

    def csv_text(self, q_deg: np.ndarray, shift_mm: np.ndarray, status: list[str]) -> str:
        """The program with joints ``q_deg`` (N, 6) in place of its own, ``shift_mm`` (N,) and
        ``status`` (N,) appended."""
        cols = [self.header.index(c) for c in Q_COLUMNS]
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow([*self.header, *ADDED_COLUMNS])
        for row, q, shift, why in zip(self.rows, q_deg, shift_mm, status, strict=True):
            cells = list(row)
            for c, v in zip(cols, q, strict=True):
                cells[c] = f"{v:.6f}"
            writer.writerow([*cells, f"{shift:.4f}", why])
        return out.getvalue()


def load_program(path) -> Program:
    """Read a program CSV; any problem is an ``InputError`` naming the file, the row and the column."""
    path = Path(path)
    header, body = read_csv(path, "program rows")
    missing = [c for c in Q_COLUMNS if c not in header]
    if missing:
        raise InputError(f"{path}: missing column {missing[0]}")
    done = [c for c in ADDED_COLUMNS if c in header]
    if done:
        raise InputError(
            f"{path}: has a {done[0]} column: it is a compensated program already, and compensating "
            "it again would apply the correction twice; compensate the original program"
        )
    repeated = next((c for c in header if header.count(c) > 1), None)
    if repeated is not None:
        raise InputError(f"{path}: column {repeated} appears twice")
    if not body:
        raise InputError(f"{path}: no program rows after the header row")
    for i, row in enumerate(body):
        if len(row) > len(header):
            raise InputError(
                f"{path}: row {i} (line {i + 2}): {len(row)} cells, but the header names {len(header)}"
            )
    rows = [row + [""] * (len(header) - len(row)) for row in body]
    q = parse_numbers(path, rows, [header.index(c) for c in Q_COLUMNS], Q_COLUMNS)
    check_joints_in_degrees(str(path), q, "program rows")
    return Program(str(path), header, rows, q)
