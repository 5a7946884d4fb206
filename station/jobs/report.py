"""The calibration report as typed values, and its shapes at the edge: the contract's REPORT.json
(``CalibrationReport.as_json``) and the corrected robot table (``corrected_table``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from calib.calibrate import Calibration
from calib.kinematics import N_DH, dh_table
from calib.models import DrawstringSetupEstimate
from calib.params import DH_KEYS, DH_NAMES, dh_to_degrees, display_factor
from calib.position import TrackerSetupEstimate
from station.formats.samples import Samples
from station.formats.tables import RobotFile


@dataclass(frozen=True)
class ErrorMetrics:
    """The contract's M: RMS, mean absolute and largest absolute row error [mm]."""

    rmse_mm: float
    mean_mm: float
    max_mm: float


@dataclass(frozen=True)
class FitMetrics:
    """Errors of one parameter vector on the training rows and, where given, the hold-out rows."""

    train: ErrorMetrics
    holdout: ErrorMetrics | None = None

    def as_json(self) -> dict:
        parts = {"train": self.train, "holdout": self.holdout}
        return {k: dataclasses.asdict(v) for k, v in parts.items() if v is not None}


@dataclass(frozen=True)
class HeldParameter:
    """A parameter the calibration held at its nominal value, and why."""

    param: str
    reason: str


@dataclass(frozen=True)
class Estimate:
    """An identified table parameter in display units (deg, mm) and its standard deviation."""

    value: float
    sigma: float


@dataclass(frozen=True)
class WorkspacePrediction:
    """Expected RMS TCP error [mm] over ``configurations`` random poses within the joint limits, and
    the RMS one calibration stays below with 95 % probability."""

    predicted_rmse_mm: float
    predicted_rmse_95_mm: float
    configurations: int


@dataclass(frozen=True)
class Selection:
    """The configurations MCS chose: training ``rows`` (0-based), their number ``n`` and the
    observability ``index`` with its ``value``."""

    rows: tuple[int, ...]
    n: int
    index: str
    value: float


@dataclass(frozen=True)
class CalibrationReport:
    """What a calibration found (the contract's "The report"); ``setup`` is the model's setup
    estimate (``calib.models.DrawstringSetupEstimate`` or ``calib.position.TrackerSetupEstimate``),
    whose fields the JSON spreads at the top level."""

    kind: str
    method: str
    before: FitMetrics
    after: FitMetrics
    setup: DrawstringSetupEstimate | TrackerSetupEstimate
    identified: tuple[str, ...]
    held: tuple[HeldParameter, ...]
    parameters: dict[str, Estimate]
    downweighted: tuple[int, ...]
    workspace: WorkspacePrediction
    warnings: tuple[str, ...]
    iterations: int
    time_s: float
    selection: Selection | None = None

    def as_json(self) -> dict:
        """The contract's REPORT.json object (keys in the contract's order, plain JSON values)."""
        out = {
            "kind": self.kind,
            "method": self.method,
            "before": self.before.as_json(),
            "after": self.after.as_json(),
            **_plain(dataclasses.asdict(self.setup)),
            "identified": list(self.identified),
            "held": [dataclasses.asdict(h) for h in self.held],
            "parameters": {name: dataclasses.asdict(e) for name, e in self.parameters.items()},
            "downweighted": list(self.downweighted),
            "workspace": dataclasses.asdict(self.workspace),
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            "time_s": self.time_s,
        }
        if self.selection is not None:
            out["selection"] = {**dataclasses.asdict(self.selection), "rows": list(self.selection.rows)}
        return out


def _plain(value):
    """Arrays and numpy scalars to lists and Python numbers, through dicts, lists and tuples."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.ndarray, np.generic)):
        return value.tolist()
    return value


def corrected_table(robot: RobotFile, cal: Calibration, samples: Samples, method: str) -> dict:
    """The robot file with the calibrated table, per-joint sigmas and provenance (TOML-ready)."""
    table = dh_to_degrees(dh_table(cal.x))
    factor = display_factor(DH_NAMES)
    sigma = (cal.sigma[:N_DH] * factor).reshape(6, 4)
    cols = DH_KEYS
    joints = []
    for j, joint in enumerate(robot.joints):
        entry = joint.model_dump(exclude={"sigma"})
        entry.update(zip(cols, table[j], strict=True))
        entry["sigma"] = {c: float(sigma[j, k]) for k, c in enumerate(cols) if np.isfinite(sigma[j, k])}
        joints.append({k: float(v) if isinstance(v, np.floating) else v for k, v in entry.items()})
    return {
        "name": robot.name,
        "convention": "dh",
        "tool_mm": list(robot.tool_mm),
        "calibration": {
            "method": method,
            "samples": samples.path,
            "n_samples": len(samples),
            "date_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "identified": [n for n in DH_NAMES if cal.identified[DH_NAMES.index(n)]],
            # the table's covariance in display units (deg, mm), held parameters considered
            "covariance_parameters": list(DH_NAMES),
            "covariance": (cal.table_covariance * np.outer(factor, factor)).tolist(),
        },
        **({"controller_hash": robot.controller_hash} if robot.controller_hash else {}),
        "joints": joints,
    }
