"""The calibration service: validated files in, one calibration by any method out.

Split as scipy's ``least_squares``: ``calibrate_samples`` builds the measurement model and validates
once (``validate``), dispatches to one solver per method (``SOLVERS``), and returns one
``CalibrationOutcome`` with a typed report (``station.jobs.report``): its checks of the fit, warnings
and advice come from ``station.jobs.fit_check``. ``MESSAGES`` word a bad parameter (a
``ParameterError`` naming it: a command maps the name to its flag). MCS-LMLC is written once
(``mcs_lmlc``), shared with ``station compare``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calib.accuracy import predicted_workspace_rmse, workspace_error_modes, workspace_rmse_bound
from calib.calibrate import (
    Calibration,
    CalibrationOptions,
    WithPrior,
    calibrate,
    correlate,
    fit_setup,
)
from calib.drawstring import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup
from calib.kinematics import dh_table
from calib.methods import ALL_METHODS, BASELINES
from calib.metrics import error_metrics
from calib.models import MeasurementModel
from calib.observability import MCSResult, select_configurations
from calib.params import DH_NAMES, dh_from_degrees, display_factor
from calib.position import PositionModel, PositionSamples
from calib.residual_map import ResidualMap, left_share
from calib.selection import TermSelection
from calib.uncertainty import covariance, row_noise
from errors import InputError, ParameterError
from station.formats.samples import Samples
from station.formats.tables import Payload, RobotFile, SetupFile
from station.jobs import absorbed
from station.jobs.fit_check import fit_check, holdout_scope, next_step, short_of_optimum, workspace_warnings
from station.jobs.report import (
    CalibrationReport,
    CrossValidation,
    CrossValidationRow,
    ErrorMetrics,
    Estimate,
    FitMetrics,
    HeldParameter,
    Provenance,
    Selection,
    WorkspacePrediction,
    now_utc,
)
from station.jobs.terms import MODELS, TermChoice, carry_over_warnings, choose_terms

METHODS = ALL_METHODS
WORKSPACE_POSES = 1000
LIMIT_MARGIN_DEG = 1.0
"""How far beyond a stated joint limit a reading may lie (overtravel, encoder) before it is refused."""
MESSAGES = {
    "method": "{method} {value!r}: must be one of {choices}",
    "terms": "{terms} {value!r}: must be one of {choices}",
    "needs_setup": "{samples}: a drawstring set needs {setup}",
    "select_needs_mcs": "{select} {value}: selecting configurations needs {method} mcs-lmlc",
    "select_range": "{select} {value}: must lie between the {unknowns} unknowns and the {n} samples",
}
"""Bad parameters; ``{method}``, ``{setup}``, ``{select}``, ``{terms}`` are parameter names (see
ParameterError)."""


@dataclass(frozen=True)
class CalibrationOutcome:
    """A finished calibration: the typed ``report``, ``calib``'s ``calibration`` (fits, covariance),
    the training ``model`` it ran on (with the terms it fitted) and the ``payload`` its gravity
    torques counted (``payload_of``), which a corrected table records."""

    report: CalibrationReport
    calibration: Calibration
    model: MeasurementModel
    payload: Payload | None = None


@dataclass(frozen=True)
class MethodFit:
    """What a solver returns: the ``calibration`` (its ``downweighted`` rows numbered in the training
    set), the MCS ``selection`` (mcs-lmlc), the least-squares ``optimum`` a baseline is judged
    against, and whether LMLC's solver found it (``lm``: its robust loss weighs the rows and its
    iteration cap applies; a baseline has neither)."""

    calibration: Calibration
    selection: MCSResult | None = None
    optimum: np.ndarray | None = None
    lm: bool = True


def calibrate_samples(
    samples: Samples,
    robot: RobotFile,
    setup: SetupFile | None,
    *,
    setup_where: str = "setup",
    holdout: Samples | None = None,
    method: str = "lmlc",
    select: int | None = None,
    terms: str = "geometric",
    notes: tuple[str, ...] = (),
    stage: Callable[[str], None] = lambda text: None,
) -> CalibrationOutcome:
    """Calibrate on ``samples`` and evaluate before/after on training and ``holdout`` rows.

    ``method`` is one of ``METHODS``; ``mcs-lmlc`` first selects ``select`` configurations (default:
    where O1 flattens). ``terms`` is one of ``station.jobs.terms.MODELS``: the joint-space terms
    fitted beside the table (``auto`` chooses them by cross-validation on ``samples`` alone).
    ``notes`` (what the caller noticed of the inputs, e.g. a flag replacing a session's robot) lead
    the report's warnings and, for a fit refused, name the likely cause. Raises ``InputError`` for
    too few samples and ``ParameterError`` for a bad ``method``, ``select``, ``terms`` or a missing
    ``setup``. ``stage(text)`` is told what it does as it goes (a command's progress lines).
    """
    t0 = time.perf_counter()
    stage("checking the rows")
    for rows in (samples, holdout):
        if rows is not None:
            check_joint_limits(rows, robot)
    model = build_model(samples, robot, setup, setup_where).by_axes()  # the fits' faster frames
    validate(model, samples.path, method, select)
    if terms not in MODELS:
        raise ParameterError(MESSAGES["terms"], value=terms, choices=", ".join(MODELS))
    payload = payload_of(robot, setup)
    if terms == "auto":
        stage("choosing the terms by cross-validation (a fit per candidate and fold)")
    choice = choose_terms(terms, model, robot.link_masses(payload), unknowns(model))
    weighing = ", then weighing the error neighbouring poses share" if choice.model.pose_groups else ""
    stage(f"fitting ({method}{weighing})")
    fit = SOLVERS[method](choice, method, select)
    stage("checking the fit and writing the report")
    elapsed = time.perf_counter() - t0
    origin = provenance(samples, robot, setup_where if setup is not None else None)
    hold_model = holdout_model(choice.model, holdout)
    report = _report(choice, hold_model, robot, method, fit, elapsed, terms, notes, origin)
    return CalibrationOutcome(report, fit.calibration, choice.model, payload)


def provenance(samples: Samples, robot: RobotFile, setup: str | None) -> Provenance:
    """What a report is of: the robot, the samples' path, the setup (where it came from), now and
    the station's version."""
    from station import installed_version

    return Provenance(
        robot.name, robot.serial, str(samples.path), setup, now_utc(), installed_version(), robot.convention
    )


def payload_of(robot: RobotFile, setup: SetupFile | None) -> Payload | None:
    """What the flange carried while measuring: the setup's payload, else the robot file's own."""
    return (setup.payload if setup is not None else None) or robot.payload


# -- the model and its validation ---------------------------------------------------------------
def drawstring_setup(setup: SetupFile, where: str) -> DrawstringSetup:
    """The maths' view of a setup file; a drawstring set needs its ``[drawstring]`` table."""
    if setup.drawstring is None:
        raise InputError(f"{where}: missing table [drawstring] (anchor_mm, length_offset_mm)")
    default_axis = setup.dial.axis if setup.dial else None
    return DrawstringSetup(
        anchor=np.array(setup.drawstring.anchor_mm),
        length_offset=setup.drawstring.length_offset_mm,
        sigma_length=setup.drawstring.sigma_mm,
        sigma_line=setup.line_sigma_mm,
        sigma_contact=setup.contact_sigma_mm,
        dial_axis={ln.id: _unit(ln.dial_axis) for ln in setup.lines if ln.dial_axis is not None},
        default_dial_axis=None if default_axis is None else _unit(default_axis),
        rho=setup.rho,
    )


def build_model(
    samples: Samples, robot: RobotFile, setup: SetupFile | None, setup_where: str
) -> MeasurementModel:
    """The measurement model of a training set, by the set's kind: a position set (tracker) starts
    its probe offset at the robot file's ``tool_mm``; a drawstring set needs the setup file."""
    return _MODEL_OF_KIND[samples.kind](samples, robot, setup, setup_where)


def _position_model(samples: Samples, robot: RobotFile, setup, setup_where: str) -> PositionModel:
    dh0 = dh_from_degrees(robot.table_deg())
    return PositionModel(model_samples(samples), dh0, np.array(robot.tool_mm))


def _drawstring_model(
    samples: Samples, robot: RobotFile, setup: SetupFile | None, setup_where: str
) -> DrawstringLineModel:
    if setup is None:
        raise ParameterError(MESSAGES["needs_setup"], samples=samples.path)
    dh0 = dh_from_degrees(robot.table_deg())
    ds_setup = drawstring_setup(setup, setup_where)
    data = model_samples(samples)
    frame = DrawstringFrame.from_nominal(data, ds_setup, dh0, robot.tool_mm)
    return DrawstringLineModel(data, ds_setup, frame, dh0, robot.tool_mm)


_MODEL_OF_KIND = {"position": _position_model, "drawstring": _drawstring_model}
_ROWS_OF_KIND = {
    "position": lambda s: PositionSamples(np.radians(s.q_deg), s.measured),
    "drawstring": lambda s: DrawstringSamples(
        np.radians(s.q_deg), s.measured, s.dial_mm, s.line, s.sweep_pass, s.t_s
    ),
}


def model_samples(samples: Samples) -> DrawstringSamples | PositionSamples:
    """A sample file's rows as the maths takes them (joints in rad)."""
    return _ROWS_OF_KIND[samples.kind](samples)


def holdout_model(model: MeasurementModel, holdout: Samples | None) -> MeasurementModel | None:
    """The training ``model`` (its frame and setup) on the hold-out rows; None without them."""
    return model.with_samples(model_samples(holdout)) if holdout is not None else None


def unknowns(model: MeasurementModel) -> int:
    """How many unknowns (table and setup) the data must determine: all but the model's gauges."""
    return len(model.names) - len(model.gauges())


def check_joint_limits(samples: Samples, robot: RobotFile) -> None:
    """Bad input if a joint reads beyond the limits the robot file states (by more than
    ``LIMIT_MARGIN_DEG``): no reading the robot can give, so a garbled reading or another robot's
    rows, which the fit would otherwise absorb into a wrong table. Joints without stated limits pass."""
    for j, joint in enumerate(robot.joints):
        if not {"q_min_deg", "q_max_deg"} & joint.model_fields_set:
            continue
        q = samples.q_deg[:, j]
        lo, hi = joint.q_min_deg - LIMIT_MARGIN_DEG, joint.q_max_deg + LIMIT_MARGIN_DEG
        out = np.flatnonzero((q < lo) | (q > hi))
        if out.size:
            i = int(out[0])
            raise InputError(
                f"{samples.path}: row {i} (line {i + 2}): q{j + 1}_deg {q[i]:g} is outside joint {j + 1}'s "
                f"limits {joint.q_min_deg:g} .. {joint.q_max_deg:g} deg in the robot file ({robot.name}): "
                f"not a reading this robot can give ({out.size} such rows; a garbled reading, or another "
                "robot's samples)"
            )


def check_enough(model: MeasurementModel, where: str) -> None:
    """Bad input unless there are at least as many samples as unknowns."""
    n, needed = len(model.samples), unknowns(model)
    if n < needed:
        raise InputError(
            f"{where}: {n} samples cannot determine {needed} unknowns (table and setup): "
            f"measure at least {needed}"
        )


def validate(model: MeasurementModel, where: str, method: str, select: int | None) -> None:
    """Everything the solvers trust: a known method, enough samples, ``select`` only for mcs-lmlc
    and between the unknowns and the samples."""
    if method not in METHODS:
        raise ParameterError(MESSAGES["method"], value=method, choices=", ".join(METHODS))
    check_enough(model, where)
    if select is None:
        return
    if method != "mcs-lmlc":
        raise ParameterError(MESSAGES["select_needs_mcs"], value=select)
    n, needed = len(model.samples), unknowns(model)
    if not needed <= select <= n:
        raise ParameterError(MESSAGES["select_range"], value=select, unknowns=needed, n=n)


# -- the solvers --------------------------------------------------------------------------------
def _lmlc(choice: TermChoice, method: str, select: int | None) -> MethodFit:
    if choice.calibration is None:
        return MethodFit(calibrate(choice.model, CalibrationOptions()))
    return MethodFit(correlate(choice.model, choice.calibration, CalibrationOptions()))


def _mcs_lmlc(choice: TermChoice, method: str, select: int | None) -> MethodFit:
    mcs, cal = mcs_lmlc(choice.model, CalibrationOptions(), select)
    return MethodFit(cal, selection=mcs)


def _baseline(choice: TermChoice, method: str, select: int | None) -> MethodFit:
    cal, optimum = baseline(choice.model, method)
    return MethodFit(cal, optimum=optimum, lm=False)


SOLVERS = {"lmlc": _lmlc, "mcs-lmlc": _mcs_lmlc, **dict.fromkeys(BASELINES, _baseline)}
"""One solver per method: ``(choice, method, select) -> MethodFit`` on ``choice.model`` (the
training rows with the terms ``--model`` chose); they trust ``validate``."""


def mcs_lmlc(
    model: MeasurementModel, options: CalibrationOptions, n_select: int | None = None
) -> tuple[MCSResult, Calibration]:
    """M9: select ``n_select`` configurations by MCS (default: where O1 flattens), then the whole
    LMLC pipeline on them; the calibration's ``downweighted`` rows are numbered in ``model``'s rows."""
    mcs = select_measurements(model, n_select)
    rows = mcs.selection.rows
    cal = calibrate(model.with_samples(model.samples.subset(rows)), options)
    return mcs, dataclasses.replace(cal, downweighted=rows[cal.downweighted])


def select_measurements(model: MeasurementModel, n_select: int | None) -> MCSResult:
    """MCS at the setup fit: the identified table's observability, setup unknowns projected out,
    some rows kept of every placement."""
    start = fit_setup(model)
    _, jac = model.residuals_and_jacobian(start.before.x)
    return select_configurations(
        jac, model.rows, start.free, model.placement_ids(), np.random.default_rng(0), n_select=n_select
    )


def baseline(model: MeasurementModel, method: str) -> tuple[Calibration, np.ndarray]:
    """One of the paper's other calibrators (``calib.baselines``) from the pipeline's common start
    and identified parameters; its uncertainty from the Jacobian at its own solution, with the
    noise LMLC fitted. Nothing is down-weighted: these methods have no robust loss. Also returns
    LMLC's solution, the optimum it is judged against."""
    from calib.baselines import BaselineOptions, run_method  # scipy.optimize: only the baselines need it

    start = calibrate(model, CalibrationOptions())
    found = run_method(method, model, start.before.x, start.identified, BaselineOptions())
    prior = WithPrior(model, model.x0)
    cov, robot_cov = covariance(prior, found.x, start.identified, 1.0, row_noise(prior, start.scale))
    sigma = np.full(len(model.names), np.nan)
    sigma[start.identified] = np.sqrt(np.diag(cov))
    after = dataclasses.replace(
        start.after, x=found.x, cost=found.cost, nit=found.iterations, nfev=found.nfev
    )
    cal = dataclasses.replace(
        start,
        after=after,
        sigma=sigma,
        covariance=cov,
        robot_covariance=robot_cov,
        downweighted=np.array([], int),
    )
    return cal, start.x


# -- the report ---------------------------------------------------------------------------------
def _report(
    choice: TermChoice,
    hold_model: MeasurementModel | None,
    robot: RobotFile,
    method: str,
    fit: MethodFit,
    elapsed: float,
    terms: str,
    notes: tuple[str, ...],
    origin: Provenance | None = None,
) -> CalibrationReport:
    model, cal = choice.model, fit.calibration
    after = metrics(model, hold_model, cal.x)
    workspace = predicted_workspace(robot, cal, model)
    nominal_q = workspace_configurations(robot)
    check, doubts = fit_check(
        model, cal, after.train, robot, notes, lm=fit.lm, workspace=workspace, nominal_q=nominal_q
    )
    messages = [*notes, *doubts]
    messages += [choice.warning] if choice.warning else []
    messages += workspace_warnings(model, cal.x, after.train, workspace)
    short = short_of_optimum(model, cal.x, fit.optimum, method)
    messages += short
    messages += carry_over_warnings(model, cal)
    held = {**choice.held, **cal.held}
    scope = holdout_scope(model, hold_model)
    return CalibrationReport(
        kind=model.kind,
        method=method,
        before=metrics(model, hold_model, cal.before.x),
        after=after,
        setup=model.setup_estimate(cal.x),
        identified=tuple(robot.param_name(n) for k, n in enumerate(DH_NAMES) if cal.identified[k]),
        held=tuple(HeldParameter(robot.param_name(p), r) for p, r in held.items()),
        parameters={robot.param_name(n): e for n, e in _parameters(cal, DH_NAMES, model.x0).items()},
        downweighted=tuple(int(r) for r in cal.downweighted),
        workspace=workspace,
        warnings=tuple(messages),
        iterations=solver_iterations(cal, fit.lm),
        time_s=round(elapsed, 4),
        selection=None if fit.selection is None else _selection(fit.selection),
        model=terms,
        terms=_parameters(cal, model.terms.names, model.x0),
        cross_validation=None if choice.selection is None else _cross_validation(choice.selection),
        discrepancy=cal.discrepancy,
        fit_check=check,
        line_errors=line_errors(model, cal.x),
        line_dial=absorbed.line_modes(model),
        provenance=origin,
        holdout_scope=scope,
        next=next_step(
            model, cal, check, after.train, workspace, method if short else None, doubts, robot.param_name
        ),
    )


def solver_iterations(cal: Calibration, lm: bool) -> int:
    """The solver's iterations: LMLC's accepted steps over its linear and robust rounds (the last
    round alone, often 1, undercounts), a baseline's own count."""
    steps = sum(1 for it in cal.after.history if it.accepted) if lm else 0
    return max(steps, int(cal.after.nit))


def line_errors(model: MeasurementModel, x: np.ndarray) -> dict[int, ErrorMetrics]:
    """Each placement's (gauge line's) row errors at ``x`` [mm]."""
    errors, ids = model.row_error_mm(x), model.placement_ids()
    return {int(i): ErrorMetrics(**error_metrics(errors[ids == i])) for i in np.unique(ids)}


def residual_rows(outcome: CalibrationOutcome) -> dict:
    """What ``station calibrate --plot`` draws (JSON-ready): each training row's error [mm] before
    and after with its placement (gauge line), the down-weighted rows, the metrics before and after
    and the predicted workspace error."""
    model, cal, report = outcome.model, outcome.calibration, outcome.report
    return {
        "kind": report.kind,
        "rows": {
            "before_mm": model.row_error_mm(cal.before.x).tolist(),
            "after_mm": model.row_error_mm(cal.x).tolist(),
            "placement": model.placement_ids().tolist(),
        },
        "downweighted": list(report.downweighted),
        "before": report.before.as_json(),
        "after": report.after.as_json(),
        "workspace": dataclasses.asdict(report.workspace),
    }


def metrics(model: MeasurementModel, hold_model: MeasurementModel | None, x: np.ndarray) -> FitMetrics:
    """The contract's ``{"train": M, "holdout": M}`` of parameters ``x`` (holdout only with rows)."""
    holdout = None if hold_model is None else _errors(hold_model, x)
    return FitMetrics(_errors(model, x), holdout)


def _errors(model: MeasurementModel, x: np.ndarray) -> ErrorMetrics:
    return ErrorMetrics(**error_metrics(model.row_error_mm(x)))


def predicted_workspace(
    robot: RobotFile, cal: Calibration, model: MeasurementModel, residual_map: ResidualMap | None = None
) -> WorkspacePrediction:
    """Expected RMS error [mm] of the measured point (the model's TCP) over random configurations
    within the joint limits, and the RMS one calibration stays below with 95 % probability: the
    parameters' uncertainty and, where the fit found one, the error neighbouring poses share that no
    table takes out (``cal.discrepancy``); with a ``residual_map``, each configuration's share of
    both counted by what the map leaves there (``calib.residual_map.left_share``: 1 far from its
    rows, so a workspace mostly far from them keeps the table's figure)."""
    q = workspace_configurations(robot)
    dh = dh_table(cal.x)
    left = None if residual_map is None else left_share(residual_map, q)
    modes = workspace_error_modes(
        dh, model.tcp_in_flange(cal.x), q, cal.robot_covariance, model.terms, model.tool_mask.any(), left
    )
    shared = cal.discrepancy.tcp_rms_mm if cal.discrepancy is not None else 0.0
    shared *= 1.0 if left is None else float(np.sqrt(np.mean(left)))
    return WorkspacePrediction(
        float(np.hypot(predicted_workspace_rmse(modes), shared)),
        float(np.hypot(workspace_rmse_bound(modes, 0.95), shared)),
        WORKSPACE_POSES,
    )


def workspace_configurations(robot: RobotFile) -> np.ndarray:
    """The random configurations [rad] (``WORKSPACE_POSES``, 6) within the joint limits over which
    a workspace error is predicted."""
    limits = np.radians(robot.limits_deg())
    return np.random.default_rng(0).uniform(limits[:, 0], limits[:, 1], (WORKSPACE_POSES, 6))


def _selection(mcs: MCSResult) -> Selection:
    rows = tuple(int(r) for r in mcs.selection.rows)
    return Selection(rows, int(mcs.n_select), "O1", mcs.selection.value)


def _parameters(cal: Calibration, names, nominal: np.ndarray) -> dict[str, Estimate]:
    """The identified parameters of ``names`` in display units, with their sigmas and the
    ``nominal`` values (internal units, as ``cal.x``) they started from."""
    factor = display_factor(cal.names)
    return {
        name: Estimate(
            float(cal.x[k] * factor[k]),
            float(cal.sigma[k] * factor[k]),
            float(nominal[k] * factor[k]),
            float((cal.x[k] - nominal[k]) * factor[k]),
        )
        for k, name in enumerate(cal.names)
        if name in names and cal.identified[k]
    }


def _cross_validation(selection: TermSelection) -> CrossValidation:
    rows = tuple(
        CrossValidationRow(s.round, s.label, s.rmse_mm, s.gain, s.kept, s.reason) for s in selection.table
    )
    nominal = selection.nominal_rmse_mm
    return CrossValidation(selection.folds, selection.min_gain, rows, selection.scheme, nominal)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)
