"""The plan: the configurations to measure, in order (contract: ``target,line,q1_deg..q6_deg``).

``station plan`` designs one; ``station sim serve`` publishes the plan its simulated robot walks
(``[sim] plan_csv``), which is where ``station sample`` looks when given no ``--plan``
(``[session] plan``).

A sweep plan (issue 37) adds an integer column ``pass``: rows sharing a pass id are consecutive
waypoints on one gauge line, swept through continuously in their order (the robot stops only at a
pass's two ends). The column is optional; a plan without it is a static plan (one capture per target
after the robot settles). Where it is present every row has a pass id, a pass's rows lie on one line
and are contiguous, and each pass is one waypoint or more.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field

from errors import InputError
from station.formats.base import (
    MAX_JOINT_DEG,
    MAX_LENGTH_MM,
    Id,
    JointAngle,
    Strict,
    id_cell,
    number_cell,
    validate,
)
from station.formats.samples import Q_COLUMNS

PLAN_COLUMNS = ("target", "line", *Q_COLUMNS)
POSE_COLUMNS = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")
"""The contact pose: TCP position and tool orientation as a rotation vector (axis times angle, as
UR's poses), base frame."""
APPROACH_COLUMNS = ("ax", "ay", "az")
"""The unit direction in which the tool moves onto the edge, base frame."""
PASS_COLUMN = "pass"
"""A sweep plan's pass id per row (optional; see the module docstring)."""


@dataclass(frozen=True)
class Plan:
    """Targets: ids (M,), gauge-line ids (M,) and joint configurations (M, 6) in degrees; where the
    plan says so, each target's contact ``pose`` (M, 6: mm and rotation vector in degrees,
    ``POSE_COLUMNS``) and ``approach`` (M, 3) unit directions (a plan written before them: None)."""

    target: np.ndarray
    line: np.ndarray
    q_deg: np.ndarray
    pose: np.ndarray | None = None
    approach: np.ndarray | None = None
    sweep_pass: np.ndarray | None = None

    @property
    def is_sweep(self) -> bool:
        return self.sweep_pass is not None

    def passes(self) -> list[np.ndarray]:
        """A sweep plan's passes in order of first appearance: each the row positions of its
        waypoints (contiguous, in sweep order)."""
        if self.sweep_pass is None:
            raise ValueError("a static plan has no passes")
        _, first = np.unique(self.sweep_pass, return_index=True)
        return [np.flatnonzero(self.sweep_pass == self.sweep_pass[i]) for i in np.sort(first)]

    def __len__(self) -> int:
        return len(self.target)

    def csv_text(self) -> str:
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        contact = self.pose is not None and self.approach is not None
        sweep = self.sweep_pass is not None
        header = PLAN_COLUMNS + (POSE_COLUMNS + APPROACH_COLUMNS if contact else ())
        writer.writerow(header + ((PASS_COLUMN,) if sweep else ()))
        for k, (t, ln, q) in enumerate(zip(self.target, self.line, self.q_deg, strict=True)):
            extra = (
                [*(f"{v:.4f}" for v in self.pose[k]), *(f"{v:.6f}" for v in self.approach[k])]
                if contact
                else []
            )
            extra += [int(self.sweep_pass[k])] if sweep else []
            writer.writerow([int(t), int(ln), *(f"{v:.6f}" for v in q), *extra])
        return out.getvalue()

    def take(self, index) -> Plan:
        """The targets at positions ``index`` (an integer array), in that order."""
        return Plan(
            self.target[index],
            self.line[index],
            self.q_deg[index],
            None if self.pose is None else self.pose[index],
            None if self.approach is None else self.approach[index],
            None if self.sweep_pass is None else self.sweep_pass[index],
        )

    def rows(self) -> list[dict]:
        """As TOML-ready rows (embedded in ``session.toml``)."""
        rows = [
            {"target": int(t), "line": int(ln), "q_deg": [float(v) for v in q]}
            for t, ln, q in zip(self.target, self.line, self.q_deg, strict=True)
        ]
        if self.sweep_pass is not None:
            for row, p in zip(rows, self.sweep_pass, strict=True):
                row["pass"] = int(p)
        return rows

    @classmethod
    def of(cls, q_deg, line) -> Plan:
        """Targets numbered 0.. in order, from configurations (M, 6) [deg] and line ids (M,)."""
        q_deg = np.asarray(q_deg, float).reshape(-1, 6)
        return cls(np.arange(len(q_deg)), np.asarray(line, int), q_deg)

    @classmethod
    def from_rows(cls, rows, where: str) -> Plan:
        """The plan from :meth:`rows` as read back from ``where`` (a session.toml), validated."""
        table = validate(_PlanTable, {"plan": rows}, where)
        if not table.plan:
            raise InputError(f"{where}: plan: no targets")
        passes = [r.sweep_pass for r in table.plan]
        if any(p is None for p in passes) and any(p is not None for p in passes):
            raise InputError(f"{where}: plan: some targets have a pass and some not")
        plan = cls(
            np.array([r.target for r in table.plan], int),
            np.array([r.line for r in table.plan], int),
            np.array([r.q_deg for r in table.plan], float).reshape(-1, 6),
            sweep_pass=None if passes[0] is None else np.array(passes, int),
        )
        return _check_passes(_unique_targets(plan, where), where)


class _PlanRow(Strict):
    target: Id
    line: Id
    q_deg: Annotated[list[JointAngle], Field(min_length=6, max_length=6)]
    sweep_pass: Id | None = Field(None, alias="pass")


class _PlanTable(Strict):
    plan: list[_PlanRow]


def _unique_targets(plan: Plan, where) -> Plan:
    ids, counts = np.unique(plan.target, return_counts=True)
    if np.any(counts > 1):
        raise InputError(f"{where}: target id {ids[counts > 1][0]} appears twice; target ids must be unique")
    return plan


def _check_passes(plan: Plan, where) -> Plan:
    """A sweep plan's passes each on one gauge line and contiguous (an ``InputError`` naming the
    first row that breaks either)."""
    if plan.sweep_pass is None:
        return plan
    p, line = plan.sweep_pass, plan.line
    seen: dict[int, int] = {}
    for i in range(len(p)):
        if i and p[i] == p[i - 1]:
            if line[i] != line[i - 1]:
                raise InputError(
                    f"{where}: row {i} (line {i + 2}): line: pass {p[i]} is on line {line[i - 1]} "
                    f"and line {line[i]}; a pass sweeps one gauge line"
                )
            continue
        if int(p[i]) in seen:
            raise InputError(
                f"{where}: row {i} (line {i + 2}): pass: pass {p[i]} resumes after other rows "
                f"(it began at row {seen[int(p[i])]}); a pass's rows must be contiguous"
            )
        seen[int(p[i])] = i
    return plan


def load_plan(path) -> Plan:
    """Read a plan CSV; any problem is an ``InputError`` naming the file, row and column."""
    path = Path(path)
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (IsADirectoryError, UnicodeDecodeError, csv.Error):
        raise InputError(f"{path}: not a plan CSV file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not rows:
        raise InputError(f"{path}: no targets after the header row")
    missing = [c for c in PLAN_COLUMNS if c not in rows[0]]
    if missing:
        raise InputError(f"{path}: missing column {missing[0]}")
    values = np.array([[_cell(path, i, row, col) for col in PLAN_COLUMNS] for i, row in enumerate(rows)])
    pose, approach = _contacts(path, rows)
    sweep = (
        np.array([_cell(path, i, row, PASS_COLUMN) for i, row in enumerate(rows)]).astype(int)
        if PASS_COLUMN in rows[0]
        else None
    )
    plan = Plan(values[:, 0].astype(int), values[:, 1].astype(int), values[:, 2:], pose, approach, sweep)
    return _check_passes(_unique_targets(plan, path), path)


def _contacts(path: Path, rows: list[dict]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The contact poses and approach directions where the plan has their columns (all or none)."""
    wanted = POSE_COLUMNS + APPROACH_COLUMNS
    present = [c for c in wanted if c in rows[0]]
    if not present:
        return None, None
    if len(present) < len(wanted):
        missing = next(c for c in wanted if c not in rows[0])
        raise InputError(
            f"{path}: has {present[0]} but not {missing}: a contact pose needs all of {', '.join(wanted)}"
        )
    values = np.array([[_cell(path, i, row, col) for col in wanted] for i, row in enumerate(rows)])
    approach = values[:, 6:]
    norm = np.linalg.norm(approach, axis=1)
    if np.any(np.abs(norm - 1.0) > 1e-3):
        i = int(np.argmax(np.abs(norm - 1.0) > 1e-3))
        raise InputError(
            f"{path}: row {i} (line {i + 2}): ax,ay,az: not a unit direction (length {norm[i]:.4g})"
        )
    return values[:, :6], approach / norm[:, None]


def _cell(path: Path, i: int, row: dict, col: str) -> float:
    """Column ``col`` of row ``i``: a target or line id, a joint reading or angle [deg], a position
    [mm] or a direction's component."""
    cell = (row[col] or "").strip()  # None: the row is shorter than the header
    try:
        if col in ("target", "line", PASS_COLUMN):
            return id_cell(cell, f"a {col} id")
        if col.endswith("_mm"):
            return number_cell(cell, MAX_LENGTH_MM, "mm")
        if col in APPROACH_COLUMNS:
            return number_cell(cell, 1.5, "(a unit direction)")
        return number_cell(cell, MAX_JOINT_DEG, "deg")
    except ValueError as exc:
        raise InputError(f"{path}: row {i} (line {i + 2}): {col}: {exc}") from None
