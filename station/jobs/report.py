"""The calibration report as typed values, and its shapes at the edge: the contract's REPORT.json
(``CalibrationReport.as_json``) and the corrected robot table (``corrected_table``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from calib.calibrate import Calibration
from calib.conventions import mdh_from_dh
from calib.discrepancy import Discrepancy
from calib.drawstring import DrawstringSetupEstimate
from calib.joint_terms import TERM_KINDS
from calib.kinematics import N_DH, dh_table
from calib.models import GROUP_PRIOR
from calib.params import DH_KEYS, DH_NAMES, dh_to_degrees, display_factor
from calib.position import TrackerSetupEstimate
from station.formats.samples import Samples
from station.formats.tables import Payload, RobotFile
from station.jobs.absorbed import LineDial
from station.jobs.residual_map import MapReport


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
    """An identified parameter in display units (deg, mm) and its standard deviation; ``nominal``
    is the robot file's value it started from and ``delta`` = ``value - nominal``."""

    value: float
    sigma: float
    nominal: float | None = None
    delta: float | None = None


@dataclass(frozen=True)
class WorkspacePrediction:
    """Expected RMS TCP error [mm] over ``configurations`` random poses within the joint limits, and
    the RMS one calibration stays below with 95 % probability."""

    predicted_rmse_mm: float
    predicted_rmse_95_mm: float
    configurations: int


@dataclass(frozen=True)
class FitCheck:
    """Does the fit agree with what was stated before measuring (``calib.consistency``)?
    ``noise_ratio``: the residual of the training rows the robust loss kept (a baseline: all), in
    stated noises, with its chi-square (``chi2`` on ``dof`` degrees of freedom, ``p_value``);
    ``excursion``: the parameter that moved most from its start, by ``excursion_tolerances`` of its
    prior (a table parameter's tolerance, the setup's stated uncertainty; ``excursion_sigmas`` in the
    JSON is the same number under its first name); whether LMLC's solver stopped at its
    ``iteration_cap`` (never for a baseline); the ``verdict``: ``consistent``, ``doubtful`` (the
    report warns) or ``inconsistent`` (``station calibrate`` refuses the result with ``refusal``);
    each gauge line's dial judged against its rows (``dial_lines``, ``station.jobs.absorbed``), what
    rows read without a dial lose (``dial_mode``) and the nominal table's expected workspace error
    (``nominal_rmse_mm``), which the calibration's 95 % bound must beat; for a residual beyond the
    noise, how alike neighbouring poses' residuals are (``neighbour_agreement``: 0 for noise, near 1
    for a smooth error) and whether that makes it an error of the robot the model misses
    (``model_error``) rather than the instruments'."""

    noise_ratio: float
    chi2: float
    dof: int
    p_value: float
    excursion: str | None
    excursion_sigmas: float
    iteration_cap: bool
    verdict: str
    refusal: str | None = None
    dial_lines: tuple[LineDial, ...] = ()
    dial_mode: str | None = None
    nominal_rmse_mm: float | None = None
    neighbour_agreement: float | None = None
    model_error: bool = False


@dataclass(frozen=True)
class Selection:
    """The configurations MCS chose: training ``rows`` (0-based), their number ``n`` and the
    observability ``index`` with its ``value``."""

    rows: tuple[int, ...]
    n: int
    index: str
    value: float


@dataclass(frozen=True)
class CrossValidationRow:
    """One line of ``--model auto``'s table: in ``round`` (0: the table alone), the model kept so
    far plus ``added`` (None: nothing) predicts left-out rows to ``rmse_mm``, a relative ``gain``
    over the round's starting model; ``kept`` whether it stayed; ``reason`` why a physically grounded
    group (the compliances; the first harmonics of the whole-turn joints: each entering together)
    was left."""

    round: int
    added: str | None
    rmse_mm: float
    gain: float
    kept: bool
    reason: str | None = None


@dataclass(frozen=True)
class CrossValidation:
    """How ``--model auto`` chose its terms: k ``folds`` of the training rows (``scheme``: what each
    leaves out), the ``min_gain`` a term must bring, every score (``rows``), and the nominal table's
    error on the same folds (``nominal_rmse_mm``: what not calibrating gives there)."""

    folds: int
    min_gain: float
    rows: tuple[CrossValidationRow, ...]
    scheme: str = ""
    nominal_rmse_mm: float | None = None


@dataclass(frozen=True)
class Provenance:
    """What a report is of, so that it stands alone: the robot (``robot_name``, its ``serial`` or
    None, its table's ``robot_convention``: ``dh`` or ``mdh``), the ``samples`` file, the
    ``setup`` (a file, or the setup a session folder embeds; None where none was used), when
    (``created_utc``, ISO 8601) and by which ``station_version``."""

    robot_name: str
    robot_serial: str | None
    samples: str
    setup: str | None
    created_utc: str
    station_version: str
    robot_convention: str | None = None

    def as_json(self) -> dict:
        robot = {"name": self.robot_name, "serial": self.robot_serial}
        if self.robot_convention is not None:
            robot["convention"] = self.robot_convention
        return {
            "robot": robot,
            "samples": self.samples,
            "setup": self.setup,
            "created_utc": self.created_utc,
            "station_version": self.station_version,
        }


ERROR_HEADER = f"{'':18}{'RMSE':>9}{'MEAN':>9}{'MAX':>9}  mm"
"""The column heads of a summary's row errors (``error_row``)."""


def error_row(label: str, rmse_mm: float, mean_mm: float, max_mm: float) -> str:
    """A summary's row of errors [mm] under ``ERROR_HEADER``: a space before each figure, so a wild
    one (a 100 m reading) does not run into the next."""
    return f"{label:18}" + "".join(f" {v:8.3f}" for v in (rmse_mm, mean_mm, max_mm))


def now_utc() -> str:
    """The time now, UTC, ISO 8601 to the second."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


@dataclass(frozen=True)
class CalibrationReport:
    """What a calibration found (the contract's "The report"); ``setup`` is the model's setup
    estimate (``calib.drawstring.DrawstringSetupEstimate`` or ``calib.position.TrackerSetupEstimate``),
    whose fields the JSON spreads at the top level. Beyond the contract's keys: ``model`` (the
    ``--model``), ``terms`` (the identified joint-space terms, as ``parameters``) and, for
    ``--model auto``, ``cross_validation``; ``discrepancy``, the joint-space error the fit was
    weighted by (``calib.discrepancy``; None for a white fit); ``fit_check``, how the fit agrees
    with the stated noise and tolerances; ``line_errors``, each gauge line's residual after the fit
    (merged into the JSON's ``lines``) and ``line_dial``, how its rows were held to the edge
    (``dial``: ``axis``, ``gated`` or ``none``, ``station.jobs.absorbed.DIAL_MODE_TEXT``);
    ``provenance`` (robot, samples, setup, date, version);
    ``holdout_scope`` (``none``, ``same lines``, ``new lines``, ``poses``: what the hold-out figure
    can speak for); ``next``, what to do now in one sentence; ``map``, the residual map
    ``station calibrate`` fitted or left off (``station.jobs.residual_map.MapReport``; None where
    none was asked of it) (docs/report.md lists every key)."""

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
    model: str = "geometric"
    terms: dict[str, Estimate] = dataclasses.field(default_factory=dict)
    cross_validation: CrossValidation | None = None
    discrepancy: Discrepancy | None = None
    fit_check: FitCheck | None = None
    line_errors: dict[int, ErrorMetrics] = dataclasses.field(default_factory=dict)
    line_dial: dict[int, str] = dataclasses.field(default_factory=dict)
    provenance: Provenance | None = None
    holdout_scope: str = "none"
    next: str = ""
    map: MapReport | None = None

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
        out["model"] = self.model
        out["terms"] = {name: dataclasses.asdict(e) for name, e in self.terms.items()}
        if self.cross_validation is not None:
            out["cross_validation"] = _plain(dataclasses.asdict(self.cross_validation))
        out["discrepancy"] = None if self.discrepancy is None else dataclasses.asdict(self.discrepancy)
        if self.fit_check is not None:
            check = dataclasses.asdict(self.fit_check)
            out["fit_check"] = {**check, "excursion_tolerances": check["excursion_sigmas"]}
        if self.line_errors and "lines" in out:
            for line in out["lines"]:
                line.update(dataclasses.asdict(self.line_errors[line["id"]]))
                if line["id"] in self.line_dial:
                    line["dial"] = self.line_dial[line["id"]]
        if self.provenance is not None:
            out.update(self.provenance.as_json())
        out["holdout_scope"] = self.holdout_scope
        if self.map is not None:
            out["map"] = self.map.as_json()
        out["next"] = self.next
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


def corrected_table(
    robot: RobotFile,
    cal: Calibration,
    samples: Samples,
    method: str,
    *,
    model: str = "geometric",
    payload: Payload | None = None,
) -> dict:
    """The robot file with the calibrated table, the identified joint-space terms (each under its
    joint, as ``calib.joint_terms`` names it), per-joint sigmas and provenance (TOML-ready); the
    ``payload`` the compliances were identified with (``CalibrationOutcome.payload``)."""
    factor = display_factor(cal.names)
    table = dh_to_degrees(dh_table(cal.x))
    flange = None
    if robot.convention == "mdh":
        table, flange = mdh_from_dh(table)
    cols = DH_KEYS
    joints = []
    named = [robot.param_name(name) for name in cal.names]
    for j, joint in enumerate(robot.joints):
        entry = joint.model_dump(exclude={"sigma", *TERM_KINDS}, exclude_none=True)
        entry.update(zip(cols, (float(v) for v in table[j]), strict=True))
        entry["sigma"] = {}
        for k, name in enumerate(named):
            joint_name, _, key = name.partition(".")
            if joint_name == f"J{j + 1}" and np.isfinite(cal.sigma[k]):
                if key in TERM_KINDS:
                    entry[key] = float(cal.x[k] * factor[k])
                entry["sigma"][key] = float(cal.sigma[k] * factor[k])
        joints.append(entry)
    out = {
        "name": robot.name,
        **({"serial": robot.serial} if robot.serial else {}),
        "convention": robot.convention,
        "tool_mm": list(robot.tool_mm),
        "calibration": {
            "method": method,
            "model": model,
            "samples": samples.path,
            "n_samples": len(samples),
            "date_utc": now_utc(),
            "identified": [robot.param_name(n) for n in DH_NAMES if cal.identified[DH_NAMES.index(n)]],
            **_covariance(cal, robot.param_name),
            **_noise_scale(cal, samples.kind),
        },
        **({"controller_hash": robot.controller_hash} if robot.controller_hash else {}),
        **({} if robot.controller.identity else {"controller": robot.controller.model_dump()}),
        "joints": joints,
    }
    if flange is not None:
        out["flange"] = {"a_mm": float(flange[0]), "alpha_deg": float(flange[1])}
    if payload is not None and any(key in TERM_KINDS for j in joints for key in j):
        out["payload"] = payload.model_dump()
    return out


def _covariance(cal: Calibration, param_name=lambda name: name) -> dict:
    """The covariance of the table and of the terms the file carries (the identified ones; a held
    term is 0 and stays out), display units (deg, mm, urad/(N m)), held parameters considered;
    a fitted TCP (a tracker's probe) is the setup's and stays out too."""
    keep = [
        i
        for i, k in enumerate(cal.robot_index)
        if k < N_DH or (cal.names[k].partition(".")[2] in TERM_KINDS and np.isfinite(cal.sigma[k]))
    ]
    index = cal.robot_index[keep]
    factor = display_factor([cal.names[k] for k in index])
    cov = cal.robot_covariance[np.ix_(keep, keep)] * np.outer(factor, factor)
    return {"covariance_parameters": [param_name(cal.names[k]) for k in index], "covariance": cov.tolist()}


def _noise_scale(cal: Calibration, kind: str) -> dict:
    """The noise the fit found per residual group (``calib.models``' groups, the prior's left out),
    in stated noises, and the kind of samples: what an unchanged robot leaves (``station verify``)."""
    scale = np.ones(GROUP_PRIOR)
    found = cal.scale[:GROUP_PRIOR]
    scale[: found.size] = found
    return {"kind": kind, "noise_scale": [float(v) for v in scale]}
