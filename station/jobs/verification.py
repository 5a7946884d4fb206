"""``station verify`` behind the command line: a corrected table judged on samples it never saw.

The samples' measurement model is built as the calibration service builds it
(``calibration.build_model``), started at the table with its joint-space terms; only the setup
unknowns are fitted (``calib.calibrate.hold_robot``: the calibration's "before" with this table
instead of the nominal one). ``calib.verification`` judges the residual against what an unchanged
robot leaves (the stated noise times the calibration's own noise scale, and the table's
uncertainty from its covariance) and names the parameters a recalibration would most likely move.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from calib.accuracy import parameter_workspace_rms
from calib.calibrate import DOWNWEIGHTED_BELOW, CalibrationOptions, hold_robot, robust_weights, setup_unknowns
from calib.consistency import chi_square_sf
from calib.joint_terms import JointTerms
from calib.kinematics import dh_table
from calib.metrics import error_metrics
from calib.models import GROUP_PRIOR, MeasurementModel
from calib.params import display_unit
from calib.residual_map import ResidualMap
from calib.special import gammaincinv
from calib.verification import Change, DriftTest, caught_changes, drift_test, likely_changes
from errors import InputError
from station.formats.samples import Samples
from station.formats.tables import RobotFile, SetupFile
from station.jobs import absorbed
from station.jobs.calibration import (
    build_model,
    check_joint_limits,
    payload_of,
    provenance,
    workspace_configurations,
)
from station.jobs.fit_check import EXCURSION_OVERWHELMING, NOISE_DOUBT_RATIO
from station.jobs.planning import USUALLY_MOVE
from station.jobs.report import ERROR_HEADER, Provenance, error_row
from station.jobs.residual_map import mapped_q_deg

DRIFT_P = 1e-3
"""The chi-square's p-value below which the residual is more than an unchanged robot leaves."""
DRIFT_EXCESS = 1.5
"""...and it must be this many times what an unchanged robot leaves: on real data the model misses
errors that differ from pose to pose, so a new set of poses leaves a little more than the training
rows did (IPA UR10, table of series B on series C: 1.2x), which thousands of rows make significant."""
LIKELY_SIGMAS = 3.0
"""A parameter is named when its change is this many of its sigmas ..."""
LIKELY_SHARE = 0.5
"""... and explains at least this share of what the best single parameter explains."""
LIKELY_MAX = 5
POSE_RESOLUTION_DEG = 0.01
"""Poses whose joints agree to this are one pose (a robot at rest reads its joints to 0.001 deg)."""
MIN_TEST_DOF = 6
"""What the distinct poses must measure beyond the setup's unknowns for a verdict."""
NOT_THIS_TABLE = EXCURSION_OVERWHELMING
CAUGHT_POWER_Z = 1.2816
"""A change counts as caught when its estimate clears the single-parameter test nine times in ten:
its mean z-score is the test's threshold plus the normal's 90 % quantile."""

MEANINGS = {
    "holds": (
        "these samples leave {ratio:.2f} times the stated noise, as an unchanged robot would "
        "({expected:.2f}: "
        "the noise the calibration itself left and the table's own uncertainty); keep using the table"
        "{missed}"
    ),
    "drifted": (
        "these samples leave {ratio:.2f} times the stated noise against {expected:.2f} for an unchanged "
        "robot (chi-square p {p}): the robot is no longer what the table describes; {likely}"
        "recalibrate (station calibrate) before relying on it"
    ),
}

NEXT = {
    ("holds", "corrected"): (
        "keep using the table; verify again after a collision, a repair or at your interval (station plan "
        "--verify, station sample, station verify)"
    ),
    ("drifted", "corrected"): (
        "recalibrate (station plan, station sample, station calibrate){moved}, then verify the new table"
    ),
    ("holds", "nominal"): (
        "calibrate if you need better than these samples' {rmse:.3f} mm RMS (station plan, station "
        "sample, station calibrate): this judged the nominal table, not a corrected one"
    ),
    ("drifted", "nominal"): (
        "calibrate the robot (station plan, station sample, station calibrate): its nominal table does "
        "not describe it to the stated noise; a check of the nominal table leaves the robot's state in "
        "the history with its current table"
    ),
}
"""V.json's ``next``: what to do now, one sentence starting with the action, by verdict and by the
kind of table judged (``table_kind``: a corrected table carries ``[calibration]``)."""


@dataclass(frozen=True)
class LineResidual:
    """One gauge line's (placement's) residual [mm]."""

    id: int
    rows: int
    rmse_mm: float
    mean_mm: float
    max_mm: float


@dataclass(frozen=True)
class Likely:
    """A parameter a recalibration would most likely move: its ``change`` and ``sigma`` in display
    units, the share of the residual it ``explains`` alone."""

    param: str
    change: float
    sigma: float
    unit: str
    explains: float

    def text(self) -> str:
        """``J2.a_mm +0.312 mm (+-0.011, 28.4 sigma)``."""
        z = abs(self.change) / self.sigma
        return f"{self.param} {self.change:+.4g} {self.unit} (+-{self.sigma:.2g}, {z:.1f} sigma)"


@dataclass(frozen=True)
class Missed:
    """What the samples would let pass: of a joint's zero and a link's length and twist (what a crash
    or wear changes), the single change (``change`` in display units) that these rows catch nine
    times in ten and that moves the tool most over the workspace
    (``workspace_mm`` RMS, after a rigid re-fit of the base); a smaller drift may pass as ``holds``.
    ``change`` None: the rows do not see ``param`` at all."""

    param: str
    change: float | None
    unit: str
    workspace_mm: float | None

    def text(self, brief: bool = False) -> str:
        """The clause a verdict ends with (``brief``: the demo's few words)."""
        if self.change is None:
            unseen = "" if brief else " at all: a change there would pass unseen"
            return f"; {'does' if brief else 'these samples do'} not see {self.param}{unseen}"
        if brief:
            return (
                f"; could miss {self.param} up to {self.change:.3g} {self.unit}, "
                f"{self.workspace_mm:.2f} mm over the workspace"
            )
        return (
            f"; these samples could miss a drift moving the tool up to {self.workspace_mm:.3f} mm RMS over "
            f"the workspace ({self.param} by {self.change:.3g} {self.unit}); poses that turn the joints "
            "further, or a second line, see more"
        )


@dataclass(frozen=True)
class VerifyReport:
    """What ``station verify`` found (the contract's V.json, ``as_json``)."""

    verdict: str
    meaning: str
    kind: str
    rmse_mm: float
    mean_mm: float
    max_mm: float
    test: DriftTest
    lines: tuple[LineResidual, ...]
    likely: tuple[Likely, ...]
    rows: int
    downweighted: tuple[int, ...]
    table: str
    samples: str
    time_s: float
    missed: Missed | None = None
    table_kind: str = "nominal"
    table_calibrated_utc: str | None = None
    provenance: Provenance | None = None
    next: str = ""
    map: dict | None = None

    def as_json(self) -> dict:
        """V.json: the contract's keys, what table it judged (``table_kind``: ``corrected`` or
        ``nominal``, ``table_calibrated_utc``: the corrected table's calibration date), the robot,
        samples, setup, date and station version (as REPORT.json), ``map`` where the table carries a
        residual map (``map_judged``: it was judged with the map's prediction added), and
        ``next``."""
        return {
            "verdict": self.verdict,
            "meaning": self.meaning,
            "kind": self.kind,
            "rmse_mm": self.rmse_mm,
            "mean_mm": self.mean_mm,
            "max_mm": self.max_mm,
            "noise_ratio": self.test.noise_ratio,
            "expected_ratio": self.test.expected_ratio,
            "chi2": self.test.chi2,
            "dof": self.test.dof,
            "p_value": self.test.p_value,
            "lines": [asdict(line) for line in self.lines],
            "likely": [asdict(p) for p in self.likely],
            "rows": self.rows,
            "downweighted": list(self.downweighted),
            "table": self.table,
            "samples": self.samples,
            "time_s": self.time_s,
            "missed": None if self.missed is None else asdict(self.missed),
            "table_kind": self.table_kind,
            "table_calibrated_utc": self.table_calibrated_utc,
            **(self.provenance.as_json() if self.provenance is not None else {}),
            **({"map": self.map} if self.map is not None else {}),
            "next": self.next,
        }


@dataclass(frozen=True)
class VerifyOutcome:
    """The ``report``, the ``model`` the samples were fitted with and its solution ``x``."""

    report: VerifyReport
    model: MeasurementModel
    x: np.ndarray

    def row_errors(self) -> dict:
        """What ``--plot`` draws (JSON-ready): each row's error [mm] and placement, the verdict."""
        return {
            "error_mm": self.model.row_error_mm(self.x).tolist(),
            "placement": self.model.placement_ids().tolist(),
            **self.report.as_json(),
        }


def verify_samples(
    samples: Samples,
    table: RobotFile,
    setup: SetupFile | None,
    *,
    table_where: str = "table",
    setup_where: str = "setup",
    robot: RobotFile | None = None,
    residual_map: ResidualMap | None = None,
) -> VerifyOutcome:
    """Judge ``table`` (a corrected table, or any robot file) on ``samples``: the setup unknowns
    fitted with the table and its terms held; ``robot`` (the nominal file, default the table) names
    the robot in the report; with the table's ``residual_map``, the table plus the map's prediction
    is judged (each row's joints moved to where the table alone reaches what table and map reach:
    ``station.jobs.residual_map.mapped_q_deg``). Raises ``InputError`` for too few samples, a joint
    beyond the table's limits, a drawstring set without a setup (``ParameterError``)."""
    t0 = time.perf_counter()
    check_joint_limits(samples, table)
    judged_samples = replace(samples, q_deg=mapped_q_deg(residual_map, samples.q_deg))
    model, x0 = table_held(judged_samples, table, setup, setup_where)
    held = setup_unknowns(model)
    check_distinct_poses(model, int(held.sum()), samples.path)
    check_dials(model, x0, samples.path)
    _, fit, fit_scale = hold_robot(model, x0)
    x = fit.x
    r, jac = model.residuals_and_jacobian(x)
    weights = robust_weights(r, model.groups, fit_scale, CalibrationOptions())
    scale = reference_scale(table, model)
    robot_cols = np.flatnonzero(~model.setup_mask)
    cov = table.covariance(table_where)
    test = drift_test(r, weights, scale, jac[:, held], jac[:, robot_cols], cov)
    candidates = np.array([k for k in robot_cols if model.names[k] not in model.gauges()], int)
    basis = (weights, scale, jac[:, held], jac[:, candidates])
    changes = likely_changes(r, *basis, candidates, jac[:, robot_cols], cov)
    check_same_table(model, changes, table, samples.path)
    drifted = is_drifted(test, changes, scale)
    likely = tuple(_likely(model, c, table.param_name) for c in named(changes)) if drifted else ()
    smallest = caught_changes(*basis, jac[:, robot_cols], cov, _z_caught(candidates))
    missed = _missed(model, table, x, candidates, smallest)
    errors = model.row_error_mm(x)
    overall = error_metrics(errors)
    verdict = "drifted" if drifted else "holds"
    kind, calibrated = table_judged(table)
    kept_low = np.asarray(weights) ** 2 < DOWNWEIGHTED_BELOW
    downweighted = np.unique(model.rows[kept_low])
    report = VerifyReport(
        verdict=verdict,
        meaning=meaning(verdict, test, likely, missed),
        kind=model.kind,
        **overall,
        test=test,
        lines=per_line(errors, model.placement_ids()),
        likely=likely,
        rows=len(model.samples),
        downweighted=tuple(int(i) for i in downweighted),
        table=table_where,
        samples=samples.path,
        time_s=round(time.perf_counter() - t0, 4),
        missed=missed,
        table_kind=kind,
        table_calibrated_utc=calibrated,
        provenance=provenance(samples, robot or table, setup_where if setup is not None else None),
        next=next_step(verdict, kind, likely, overall["rmse_mm"]),
        map=None if residual_map is None else map_judged(residual_map, samples),
    )
    return VerifyOutcome(report, model, x)


def map_judged(found: ResidualMap, samples: Samples) -> dict:
    """V.json's ``map``: judged with it, and the size of its prediction at the samples [mm] (3-D
    RMS and largest)."""
    size = np.linalg.norm(found.predict(np.radians(samples.q_deg))[0], axis=1)
    return {
        "judged": True,
        "predicted_rmse_mm": float(np.sqrt(np.mean(size**2))),
        "predicted_max_mm": float(size.max()),
    }


def table_held(
    samples: Samples, table: RobotFile, setup: SetupFile | None, setup_where: str
) -> tuple[MeasurementModel, np.ndarray]:
    """The measurement model of ``samples`` with ``table``'s joint-space terms, and its start
    ``x0`` with the robot's unknowns at the table's values (the setup's at their rough values):
    what ``calib.calibrate.hold_robot`` fits the setup unknowns from, the table held."""
    model = build_model(samples, table, setup, setup_where)
    chain = table.model()
    links = table.link_masses(payload_of(table, setup))
    model = model.with_terms(JointTerms(table.terms(), chain.dh, links))
    x0 = model.x0.copy()
    x0[~model.setup_mask] = np.concatenate([chain.dh.ravel(), chain.term_values])
    return model, x0


def table_judged(table: RobotFile) -> tuple[str, str | None]:
    """What kind of table ``table`` is (``corrected``: it carries ``[calibration]``, else
    ``nominal``) and, for a corrected one, its calibration date (``date_utc``)."""
    if not table.calibration:
        return "nominal", None
    when = table.calibration.get("date_utc")
    return "corrected", when if isinstance(when, str) else None


def next_step(verdict: str, kind: str, likely: tuple[Likely, ...], rmse_mm: float) -> str:
    """What to do now (``NEXT``) after ``verdict`` on a ``kind`` of table (``corrected`` or
    ``nominal``), naming the parameters most likely moved; ``rmse_mm``: the samples' residual [mm]."""
    moved = ""
    if likely:
        moved = f" after checking what moved ({', '.join(p.param for p in likely[:3])}: a collision or wear?)"
    return NEXT[verdict, kind].format(moved=moved, rmse=rmse_mm)


def check_distinct_poses(model: MeasurementModel, unknowns: int, where: str) -> None:
    """Bad input unless the samples' distinct poses (joints to ``POSE_RESOLUTION_DEG``) measure
    ``MIN_TEST_DOF`` more numbers than the setup's ``unknowns`` take up: one pose read fifteen times
    tells its noise, not whether the table holds elsewhere."""
    q = np.round(np.degrees(model.samples.q) / POSE_RESOLUTION_DEG)
    distinct = len(np.unique(q, axis=0))
    per_pose = (np.count_nonzero(model.groups != GROUP_PRIOR)) / len(model.samples)
    needed = int(np.ceil((unknowns + MIN_TEST_DOF) / per_pose))
    if distinct < needed:
        raise InputError(
            f"{where}: {len(model.samples)} samples at {distinct} distinct pose{'s' if distinct > 1 else ''} "
            f"cannot judge a table: the setup's {unknowns} unknowns take up what they measure; measure "
            f"at least {needed} distinct poses (station plan --verify)"
        )


def check_dials(model: MeasurementModel, x0: np.ndarray, where: str) -> None:
    """Bad input where a line's dial readings contradict its stated ``dial_axis`` (flipped, another
    axis, not this edge's): judged as ``station calibrate`` judges them (``absorbed.judge_dials``),
    on a setup fit without the readings, the table held at ``x0``."""
    if model.kind != "drawstring" or not absorbed.judged_lines(model):
        return
    _, free_fit, _ = hold_robot(absorbed.dial_free(model), x0)
    refusal = absorbed.dial_refusal(absorbed.judge_dials(model, free_fit.x))
    if refusal:
        raise InputError(f"{where}: {refusal}; the table cannot be judged until it is, nothing recorded")


def check_same_table(model: MeasurementModel, changes: list[Change], table: RobotFile, where: str) -> None:
    """Bad input where the change that best explains the residual lies ``NOT_THIS_TABLE``
    tolerances or more from the table (a robot drifts by a fraction of a degree or a millimetre;
    another robot's table, or a wrong setup, by tens of degrees): ``station calibrate`` refuses the
    same at ``EXCURSION_OVERWHELMING``."""
    if not changes:
        return
    best = changes[0]
    tolerance = model.prior_sigma()[best.index]
    if abs(best.change) < NOT_THIS_TABLE * tolerance:
        return
    name = model.names[best.index]
    factor, unit = display_unit(name)
    raise InputError(
        f"{where}: these samples do not fit this table: {table.param_name(name)} would have moved "
        f"{best.change * factor:+.4g} {unit}, {abs(best.change) / tolerance:.0f} times its tolerance "
        f"({tolerance * factor:.3g} {unit}); likely cause: a table of another robot (it describes the "
        f"{table.name}) or a wrong setup file, not a drift; nothing recorded"
    )


def _z_caught(candidates: np.ndarray) -> float:
    """The mean z-score of a change the single-parameter test (``DRIFT_P``, Bonferroni over the
    candidates) catches nine times in ten."""
    p = DRIFT_P / max(len(candidates), 1)
    return float(np.sqrt(2.0 * gammaincinv(0.5, 1.0 - p))) + CAUGHT_POWER_Z


def _missed(
    model: MeasurementModel, table: RobotFile, x: np.ndarray, candidates: np.ndarray, smallest: np.ndarray
) -> Missed | None:
    """Of the smallest changes the rows catch (``smallest``, internal units, per candidate column of
    ``x``) of what a crash or wear changes (``USUALLY_MOVE``, what ``station plan --verify`` aims at)
    and the calibration determined (a held parameter is as uncertain as its tolerance anyway, which
    the predicted workspace error counts), the one that moves the tool most over the workspace."""
    robot_cols = np.flatnonzero(~model.setup_mask)
    tcp = model.tcp_in_flange(x)
    reach = parameter_workspace_rms(dh_table(x), tcp, workspace_configurations(table), model.terms)
    reach = reach[np.searchsorted(robot_cols, candidates)]
    identified = (table.calibration or {}).get("identified")
    usual = np.array(
        [
            model.names[k].partition(".")[2] in USUALLY_MOVE
            and (not identified or table.param_name(model.names[k]) in identified)
            for k in candidates
        ],
        bool,
    )
    moves = usual & (reach > 1e-9)  # a change the base's re-registration cannot take up
    if not moves.any():
        return None
    blind = np.where(moves, smallest * np.where(moves, reach, 1.0), 0.0)
    k = int(np.argmax(blind))
    factor, unit = display_unit(model.names[candidates[k]])
    name = table.param_name(model.names[candidates[k]])
    if not np.isfinite(blind[k]):
        return Missed(name, None, unit, None)
    return Missed(name, float(smallest[k] * factor), unit, float(blind[k]))


def is_drifted(test: DriftTest, changes: list[Change], scale: np.ndarray) -> bool:
    """More than an unchanged robot leaves: the residual's chi-square, or the single parameter that
    best explains it (its z-score, Bonferroni over the candidates), rejects at ``DRIFT_P``; where
    the calibration itself left more than the stated noise (the model misses errors), the residual
    must also exceed what it left by ``DRIFT_EXCESS`` (the calibration's own fit check doubts a fit
    at ``NOISE_DOUBT_RATIO`` times the stated noise; within it, the noise was stated loosely)."""
    if np.any(scale >= NOISE_DOUBT_RATIO) and test.excess < DRIFT_EXCESS:
        return False
    if test.p_value < DRIFT_P:
        return True
    if not changes:
        return False
    best = changes[0]
    return chi_square_sf(best.z**2, 1) * len(changes) < DRIFT_P


def reference_scale(table: RobotFile, model: MeasurementModel) -> np.ndarray:
    """Per residual row, what an unchanged robot leaves in stated noises: the calibration's fitted
    noise scale of that row's group (``[calibration] noise_scale``, written for the same kind of
    samples), at least 1 (1 without it: a nominal table, another kind of instrument)."""
    record = table.calibration or {}
    scale = np.ones(GROUP_PRIOR)
    given = record.get("noise_scale")
    if record.get("kind") == model.kind and isinstance(given, list) and len(given) == GROUP_PRIOR:
        scale = np.maximum(np.nan_to_num(np.array(given, float), nan=1.0), 1.0)
    return scale[model.groups]


def named(changes: list[Change]) -> list[Change]:
    """The changes worth naming: ``LIKELY_SIGMAS`` sigmas or more, explaining at least
    ``LIKELY_SHARE`` of what the best explains, at most ``LIKELY_MAX``."""
    if not changes:
        return []
    best = changes[0].explains
    keep = [c for c in changes if c.z >= LIKELY_SIGMAS and c.explains >= LIKELY_SHARE * best]
    return keep[:LIKELY_MAX]


def _likely(model: MeasurementModel, change: Change, param_name) -> Likely:
    """``change`` in display units, its parameter named as the table does (``param_name``)."""
    factor, unit = display_unit(model.names[change.index])
    name = param_name(model.names[change.index])
    return Likely(name, change.change * factor, change.sigma * factor, unit, round(change.explains, 4))


def per_line(errors: np.ndarray, placement: np.ndarray) -> tuple[LineResidual, ...]:
    """The residual of each placement (gauge line id >= 0)."""
    out = []
    for lid in np.unique(placement[placement >= 0]):
        m = error_metrics(errors[placement == lid])
        out.append(LineResidual(int(lid), int(np.sum(placement == lid)), **m))
    return tuple(out)


def meaning(verdict: str, test: DriftTest, likely: tuple[Likely, ...], missed: Missed | None = None) -> str:
    """What the verdict means, in one sentence; a ``holds`` says what the samples could miss."""
    p = "< 1e-300" if test.p_value < 1e-300 else f"{test.p_value:.1e}"
    what = ""
    if likely:
        what = "most likely moved: " + "; ".join(item.text() for item in likely) + "; "
    blind = "" if missed is None else missed.text()
    return MEANINGS[verdict].format(
        ratio=test.noise_ratio, expected=test.expected_ratio, p=p, likely=what, missed=blind
    )


def judged(report: VerifyReport) -> str:
    """Which table was judged: ``corrected table, calibrated 2026-...`` or ``nominal table``."""
    when = f", calibrated {report.table_calibrated_utc}" if report.table_calibrated_utc else ""
    return f"{report.table_kind} table{when}"


def summary(report: VerifyReport) -> str:
    """A short human summary: the residual overall and per line, the test, the verdict."""
    lines = [
        f"{report.kind} verification of {report.table} ({judged(report)}) on {report.rows} samples "
        f"({report.time_s:.2f} s)",
        ERROR_HEADER,
        error_row("all rows", report.rmse_mm, report.mean_mm, report.max_mm),
    ]
    for line in report.lines:
        lines.append(error_row(f"line {line.id} ({line.rows})", line.rmse_mm, line.mean_mm, line.max_mm))
    t = report.test
    lines.append(
        f"residual {t.noise_ratio:.2f} x the stated noise, {t.expected_ratio:.2f} expected of an "
        f"unchanged robot (chi-square {t.chi2:.4g} on {t.dof}, p {t.p_value:.2g})"
    )
    if report.downweighted:
        lines.append(f"down-weighted rows (gross readings): {list(report.downweighted)}")
    if report.map is not None:
        lines.append(
            f"judged with the table's residual map (its prediction at these samples: "
            f"{report.map['predicted_rmse_mm']:.3f} mm RMS)"
        )
    lines.append(f"verdict: {report.verdict} ({report.meaning})")
    lines.append(f"next: {report.next}")
    return "\n".join(lines)
