"""The calibration service: validated files in, one calibration by any method out.

Split as scipy's ``least_squares``: ``calibrate_samples`` builds the measurement model and validates
once (``validate``), dispatches to one solver per method (``SOLVERS``), and returns one
``CalibrationOutcome`` with a typed report (``station.jobs.report``). Messages come from tables:
``MESSAGES`` for a bad parameter (a ``ParameterError`` naming it: a command maps the name to its
flag), ``WARNINGS`` for the report. MCS-LMLC is written once (``mcs_lmlc``), shared with
``station compare``.
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
    covariance,
    fit_setup,
    robust_weights,
    row_noise,
)
from calib.consistency import NoiseTest, excursions, neighbour_agreement, noise_test, wild_rows
from calib.kinematics import N_DH, dh_table
from calib.methods import ALL_METHODS, BASELINES
from calib.metrics import error_metrics
from calib.models import (
    DrawstringFrame,
    DrawstringLineModel,
    DrawstringSamples,
    DrawstringSetup,
    MeasurementModel,
)
from calib.observability import MCSResult, select_configurations
from calib.params import DH_NAMES, dh_from_degrees, display_factor, display_unit
from calib.position import PositionModel, PositionSamples
from calib.residual_map import ResidualMap, left_share
from calib.selection import TermSelection
from errors import InputError, ParameterError
from station.formats.samples import Samples
from station.formats.tables import Payload, RobotFile, SetupFile
from station.jobs import absorbed
from station.jobs.report import (
    CalibrationReport,
    CrossValidation,
    CrossValidationRow,
    ErrorMetrics,
    Estimate,
    FitCheck,
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
WORKSPACE_WARNING_RATIO, WORKSPACE_WARNING_FLOOR_MM = 10.0, 0.5
"""Warn when the predicted workspace error exceeds both this many times the training fit and this."""
LIMIT_MARGIN_DEG = 1.0
"""How far beyond a stated joint limit a reading may lie (overtravel, encoder) before it is refused."""
SHORT_OF_OPTIMUM_RATIO = 1.5
"""Warn when a method's whitened residual RMS exceeds LMLC's by this factor."""
NOISE_DOUBT_RATIO, NOISE_DOUBT_P = 2.0, 1e-3
"""Warn when the kept rows' residual exceeds this many stated noises and the chi-square test rejects
the stated noise at this level. Within 2x is the noise stated loosely (on a simulated cell the
joint-reading noise seen through the arm lifts the drawstring's residual to about 1.15x)."""
NEIGHBOURS_ALIKE, NEIGHBOURS_ALIKE_SE = 0.25, 4.0
"""Residuals beyond the noise whose neighbouring poses agree this much (``neighbour_agreement``) and
this many of its standard errors under noise (``1 / sqrt(N k)``) are an error of the robot the model
does not express, not the instruments' (the real UR10 of the IPA data: 0.5; simulated noise: 0 +-
0.1)."""
OVERWHELMING_RATIO = 100.0
"""A residual this many times the stated noise: the rows are not this robot's and setup's (a JR680
session fitted with the UR10's table leaves 700x, a real UR10 on its own table 5x)."""
EXCURSION_DOUBT, EXCURSION_OVERWHELMING = 10.0, 100.0
"""Prior sigmas (a table parameter's tolerance, the setup's stated uncertainty) a parameter may move
before a warning, and before the fit is refused."""
WILD_FACTOR = 100.0
"""A row whose error before calibration is this many times the median row's is a wild reading (on
simulated and real cells the largest row is 2-8 times the median, whatever the table)."""
MIXED_FRACTION = 0.2
"""Down-weighted rows beyond this fraction, with all rows' residual beyond ``OVERWHELMING_RATIO``:
not a few gross readings but rows of another cell."""

MESSAGES = {
    "method": "{method} {value!r}: must be one of {choices}",
    "terms": "{terms} {value!r}: must be one of {choices}",
    "needs_setup": "{samples}: a drawstring set needs {setup}",
    "select_needs_mcs": "{select} {value}: selecting configurations needs {method} mcs-lmlc",
    "select_range": "{select} {value}: must lie between the {unknowns} unknowns and the {n} samples",
}
"""Bad parameters; ``{method}``, ``{setup}``, ``{select}``, ``{terms}`` are parameter names (see
ParameterError)."""

WARNINGS = {
    "workspace": (
        "fits {cover} to {fit:.3f} mm; predicted workspace error {predicted:.2f} mm "
        "(up to {bound:.2f} mm, 95 %); {next_measurement}"
    ),
    "short_of_optimum": (
        "{method} stopped short of the least-squares optimum (whitened residual RMS {rms:.2f} against "
        "{best:.2f} for lmlc): its table is worse than the data allows and the predicted workspace "
        "error does not apply to it"
    ),
    "noise": (
        "the fit leaves residuals {ratio:.1f} times the stated noise (chi-square {chi2:.4g} on {dof} "
        "degrees of freedom, p {p}): the instruments read worse than stated, or the model misses an "
        "error the rows show (neighbouring poses agree {agreement:.2f}: too little to tell); then the "
        "predicted workspace error, which counts the parameters' uncertainty, leaves out the "
        "{rmse:.3f} mm the model does not explain"
    ),
    "model_error": (
        "the fit leaves residuals {ratio:.1f} times the stated noise (chi-square {chi2:.4g} on {dof} "
        "degrees of freedom, p {p}) and neighbouring poses err alike (agreement {agreement:.2f}): "
        "the robot has an error this model does not express, not the instruments; the predicted "
        "workspace error, which counts the parameters' uncertainty, leaves out the {rmse:.3f} mm the "
        "fit leaves"
    ),
    "model_error_shared": (
        "the fit leaves residuals {ratio:.1f} times the stated noise (chi-square {chi2:.4g} on {dof} "
        "degrees of freedom, p {p}) and poses within {length:g} deg of each other share that error "
        "(restricted log-likelihood +{gain:.0f} over independent rows): the robot has an error this "
        "model does not express, not the instruments; the fit weighed such poses together, and the "
        "predicted workspace error counts that error ({shared:.3f} mm RMS at a pose) beside the "
        "parameters' uncertainty"
    ),
    "iteration_cap": (
        "the solver stopped at its cap of {nit} iterations before converging: the table may be short "
        "of the optimum"
    ),
    "excursion": "{moves}: far beyond what was known before measuring; check the {files}",
    "wild": (
        "{rows}: error before calibration up to {ratio:.0f} times the median row's ({worst:.4g} mm "
        "against {median:.3g} mm): a wild reading; check {these}"
    ),
    "refusal": "these samples do not fit this robot and setup: {evidence}; likely cause: {cause}",
}


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
    check, doubts = fit_check(model, cal, after.train, robot, notes, lm=fit.lm, workspace=workspace)
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


HOLDOUT_SCOPES = {
    "none": (
        "no --holdout: every figure but the predicted workspace error comes from the training rows' "
        "gauge lines (the cross-validation too) and says nothing about the rest of the workspace"
    ),
    "none, poses": (
        "no --holdout: every figure but the predicted workspace error and the cross-validation "
        "(regions of these poses, each left out in turn) comes from the training poses; `station "
        "verify` on poses the calibration never saw checks the rest"
    ),
    "same lines": (
        "the hold-out lies on the training's gauge lines: it shows how the table repeats there and "
        "says nothing about the rest of the workspace (the predicted workspace error does; `station "
        "verify` on a placement the calibration never saw checks it)"
    ),
    "poses": "the hold-out poses were never fitted: their error is the table's on those poses",
}
"""What the hold-out figure can speak for (the report's ``holdout_scope``), in one sentence each."""

NEXT = {
    "wild": (
        "re-measure {rows} (error before calibration up to {ratio:.0f} times the median row's: check "
        "the cable and the gauge contact), then calibrate again"
    ),
    "noise": (
        "re-measure after checking the instruments and the setup's sigma_mm: the fit leaves "
        "{ratio:.1f} times the stated noise, so the table and its predicted workspace error are not "
        "to be trusted yet"
    ),
    "model_error": (
        "accept with care: the robot errs beyond this model (neighbouring poses share the {ratio:.1f} "
        "times the stated noise the fit leaves), so expect about the fit's {fit:.3f} mm RMS where it "
        "works, not the predicted {predicted:.3f} mm; measure where it will work to check"
    ),
    "model_error_shared": (
        "accept with care: the robot errs beyond this model (poses within {length:g} deg of each other "
        "share about {shared:.3f} mm RMS), which the predicted {predicted:.3f} mm counts; measure "
        "where it will work to check"
    ),
    "excursion": (
        "check the {files} ({name} moved {z:.0f} times its tolerance), then calibrate again; "
        "re-measure if they are right"
    ),
    "iteration_cap": (
        "do not use the table yet: the solver stopped at its iteration cap; check the warnings and "
        "re-measure the rows they name"
    ),
    "short_of_optimum": (
        "calibrate again with --method lmlc: {method} stopped short of the least-squares optimum"
    ),
    "workspace": (
        "add a placement: {next_measurement}; the predicted workspace error {predicted:.2f} mm "
        "(95 %: {bound:.2f} mm) is far above the fit's {fit:.3f} mm"
    ),
    "doubtful": (
        "check what the fit check's {n} warning{s} name (the rows, the dial, the files) before "
        "accepting; re-measure what they point at"
    ),
    "accept": "accept: predicted workspace error {predicted:.3f} mm RMS (95 %: below {bound:.3f} mm){rows}",
}
"""The report's ``next``: what to do now, one sentence, starting with the action."""


def holdout_scope(model: MeasurementModel, hold_model: MeasurementModel | None) -> str:
    """What the hold-out figure can speak for (a key of ``HOLDOUT_SCOPES``): a drawstring hold-out
    shares the training's gauge lines (their fitted lines judge it), a tracker's poses are new."""
    if hold_model is None:
        return "none" if model.kind == "drawstring" else "none, poses"
    return "same lines" if model.kind == "drawstring" else "poses"


def line_errors(model: MeasurementModel, x: np.ndarray) -> dict[int, ErrorMetrics]:
    """Each placement's (gauge line's) row errors at ``x`` [mm]."""
    errors, ids = model.row_error_mm(x), model.placement_ids()
    return {int(i): ErrorMetrics(**error_metrics(errors[ids == i])) for i in np.unique(ids)}


def next_step(
    model: MeasurementModel,
    cal: Calibration,
    check: FitCheck,
    fit: ErrorMetrics,
    workspace: WorkspacePrediction,
    short_of: str | None,
    doubts: list[str] = (),
    param_name: Callable[[str], str] = lambda name: name,
) -> str:
    """What to do now, in one sentence (``NEXT``): re-measure wild rows or noisy instruments, check
    the files a parameter ran away from, mind the solver, add a placement where the workspace is not
    yet determined, check any other doubt of the fit check (``doubts``, its warnings), else accept.
    ``short_of``: the method that stopped short of the optimum; ``param_name``: the robot file's
    name of a parameter (``RobotFile.param_name``), as ``check.excursion`` gives it."""
    before = np.abs(model.row_error_mm(cal.before.x))
    wild = wild_rows(before, WILD_FACTOR)
    if wild.size:
        rows = ("row " if wild.size == 1 else "rows ") + ", ".join(str(r) for r in wild[:10])
        return NEXT["wild"].format(rows=rows, ratio=before[wild].max() / np.median(before))
    if check.noise_ratio >= NOISE_DOUBT_RATIO and check.p_value < NOISE_DOUBT_P:
        predicted = workspace.predicted_rmse_mm
        if cal.discrepancy is not None:
            d = cal.discrepancy
            return NEXT["model_error_shared"].format(
                length=d.length_scale_deg, shared=d.tcp_rms_mm, predicted=predicted
            )
        if check.model_error:
            return NEXT["model_error"].format(ratio=check.noise_ratio, fit=fit.rmse_mm, predicted=predicted)
        return NEXT["noise"].format(ratio=check.noise_ratio)
    if check.excursion is not None and check.excursion_sigmas >= EXCURSION_DOUBT:
        k = [param_name(name) for name in model.names].index(check.excursion)
        files = "setup" if model.setup_mask[k] else "robot file"
        return NEXT["excursion"].format(files=files, name=check.excursion, z=check.excursion_sigmas)
    if check.iteration_cap:
        return NEXT["iteration_cap"]
    if short_of is not None:
        return NEXT["short_of_optimum"].format(method=short_of)
    predicted, bound = workspace.predicted_rmse_mm, workspace.predicted_rmse_95_mm
    if predicted > max(WORKSPACE_WARNING_RATIO * fit.rmse_mm, WORKSPACE_WARNING_FLOOR_MM):
        advice = model.measurement_advice(cal.x)
        return NEXT["workspace"].format(
            next_measurement=advice.next_measurement, predicted=predicted, bound=bound, fit=fit.rmse_mm
        )
    if doubts:
        return NEXT["doubtful"].format(n=len(doubts), s="" if len(doubts) == 1 else "s")
    n = len(cal.downweighted)
    rows = f"; {n} rows down-weighted as gross readings" if n else ""
    return NEXT["accept"].format(predicted=predicted, bound=bound, rows=rows)


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


def workspace_warnings(
    model: MeasurementModel, x: np.ndarray, fit: ErrorMetrics, workspace: WorkspacePrediction
) -> list[str]:
    """Say when the samples fit well but cannot deliver that accuracy over the workspace, and what
    to measure next: the model knows."""
    predicted = workspace.predicted_rmse_mm
    if predicted <= max(WORKSPACE_WARNING_RATIO * fit.rmse_mm, WORKSPACE_WARNING_FLOOR_MM):
        return []
    advice = model.measurement_advice(x)
    return [
        WARNINGS["workspace"].format(
            cover=advice.cover,
            fit=fit.rmse_mm,
            predicted=predicted,
            bound=workspace.predicted_rmse_95_mm,
            next_measurement=advice.next_measurement,
        )
    ]


def short_of_optimum(
    model: MeasurementModel, x: np.ndarray, optimum: np.ndarray | None, method: str
) -> list[str]:
    """A warning when a method stopped well short of the least-squares optimum: its sigmas and
    predicted workspace error describe the optimum, not where it stopped."""
    if optimum is None:
        return []
    rms, best = (float(np.sqrt(np.mean(model.residuals(v) ** 2))) for v in (x, optimum))
    if rms <= SHORT_OF_OPTIMUM_RATIO * best:
        return []
    return [WARNINGS["short_of_optimum"].format(method=method, rms=rms, best=best)]


def fit_check(
    model: MeasurementModel,
    cal: Calibration,
    fit: ErrorMetrics,
    robot: RobotFile,
    notes: tuple[str, ...],
    *,
    lm: bool = True,
    workspace: WorkspacePrediction | None = None,
) -> tuple[FitCheck, list[str]]:
    """How the fit agrees with the stated noise and tolerances, and the warnings it calls for: a
    residual beyond the noise (chi-square), the iteration cap, a parameter far beyond its prior.
    Overwhelming evidence (a residual hundreds of times the noise, a fifth of the rows that far
    off, a parameter moved a hundred tolerances) makes the verdict ``inconsistent``, its
    ``refusal`` naming the likely cause (the first of ``notes``, else a wild reading, else what the
    evidence points at). Judged at ``cal.x`` on every row of ``model`` (the training set, whatever
    subset the solver saw), weighted by LMLC's robust loss where ``lm`` (else every row counts, and
    there is no iteration cap). The mistakes of ``station.jobs.absorbed`` (a dial axis its readings
    contradict, many rows down-weighted) add their warnings and refusal, and a ``workspace``
    prediction whose 95 % bound does not beat the nominal table's expected error is refused."""
    r = model.residuals(cal.x)
    options = CalibrationOptions() if lm else CalibrationOptions(loss="linear")
    weights = robust_weights(r, model.groups, cal.scale, options)
    found = absorbed.findings(model, cal, weights)
    nominal = workspace and absorbed.nominal_rmse(model, cal, workspace_configurations(robot))
    test = noise_test(r, weights, int(cal.identified.sum()))
    agreement = _agreement(model, cal) if _beyond_noise(test) else None
    capped = bool(lm and cal.after.status == 0)
    z = excursions(cal.x, model.x0, model.prior_sigma(), cal.identified)
    wild = _wild(model, cal)
    messages = [wild] if wild else []
    messages += [*found.warnings, *_doubts(model, cal, test, z, fit, capped, agreement, robot.param_name)]
    refusal = _refusal(model, cal, test, z, fit, robot, (*notes, *([wild] if wild else [])))
    refusal = refusal or _absorbed_refusal(found, workspace, nominal)
    verdict = "inconsistent" if refusal else "doubtful" if messages else "consistent"
    top = int(np.argmax(z))
    check = FitCheck(
        noise_ratio=test.ratio,
        chi2=test.chi2,
        dof=test.dof,
        p_value=test.p_value,
        excursion=robot.param_name(model.names[top]) if z[top] > 0 else None,
        excursion_sigmas=float(z[top]),
        iteration_cap=capped,
        verdict=verdict,
        refusal=refusal,
        dial_lines=found.dials,
        dial_mode=absorbed.dial_mode(found, model),
        nominal_rmse_mm=nominal,
        neighbour_agreement=None if agreement is None else agreement[0],
        model_error=agreement is not None and agreement[1],
    )
    return check, messages


def _beyond_noise(test: NoiseTest) -> bool:
    """The chi-square rejects the stated noise and the residual is ``NOISE_DOUBT_RATIO`` of it or more."""
    return test.ratio >= NOISE_DOUBT_RATIO and test.p_value < NOISE_DOUBT_P


def _agreement(model: MeasurementModel, cal: Calibration) -> tuple[float, bool]:
    """How alike neighbouring poses' residuals are, and whether that makes them the robot's error (so
    does an error the fit found poses share: ``cal.discrepancy``)."""
    r = model.row_residuals(cal.x)
    value = neighbour_agreement(model.samples.q, r)
    alike = value >= max(NEIGHBOURS_ALIKE, NEIGHBOURS_ALIKE_SE / np.sqrt(r.size))
    return value, bool(alike or cal.discrepancy is not None)


def _absorbed_refusal(
    found: absorbed.Findings, workspace: WorkspacePrediction | None, nominal: float | None
) -> str | None:
    """A mistake ``station.jobs.absorbed`` names with its fix, or a calibration on lines read
    without a dial predicted to keep more than ``absorbed.NOMINAL_SHARE`` of the nominal table's
    expected error; None if neither."""
    if found.refusal:
        return f"{found.refusal}; nothing else in the fit can be trusted until it is"
    weak = workspace and nominal and workspace.predicted_rmse_mm >= absorbed.NOMINAL_SHARE * nominal
    if found.unread and weak:
        return (
            f"its predicted workspace error {workspace.predicted_rmse_mm:.2f} mm is over a third of the "
            f"nominal table's expected {nominal:.2f} mm (both from the tolerances): the samples cannot be "
            "trusted to improve on the nominal table; measure more rows, on more lines, or with a dial"
        )
    return None


def _doubts(
    model: MeasurementModel,
    cal: Calibration,
    test: NoiseTest,
    z: np.ndarray,
    fit: ErrorMetrics,
    capped: bool,
    agreement: tuple[float, bool] | None = None,
    param_name: Callable[[str], str] = lambda name: name,
) -> list[str]:
    """The warnings of a fit that may still stand: a residual beyond the stated noise (the chi-square
    rejects it and it is ``NOISE_DOUBT_RATIO`` times the noise or more; ``agreement``: how alike
    neighbouring poses' residuals are, and whether that makes it the robot's error), the iteration
    cap reached, parameters ``EXCURSION_DOUBT`` prior sigmas or more from their start. ``capped``:
    the solver stopped at its iteration cap; ``param_name``: the robot file's name of a parameter."""
    messages = []
    if _beyond_noise(test):
        p = "< 1e-300" if test.p_value < 1e-300 else f"{test.p_value:.1e}"
        value, robot = agreement if agreement is not None else (float("nan"), False)
        figures = dict(ratio=test.ratio, chi2=test.chi2, dof=test.dof, p=p, rmse=fit.rmse_mm, agreement=value)
        key = "model_error" if robot else "noise"
        if cal.discrepancy is not None:
            d = cal.discrepancy
            key = "model_error_shared"
            figures.update(length=d.length_scale_deg, gain=d.loglik_gain, shared=d.tcp_rms_mm)
        messages.append(WARNINGS[key].format(**figures))
    if capped:
        messages.append(WARNINGS["iteration_cap"].format(nit=cal.after.nit))
    order = [k for k in np.argsort(-z) if z[k] >= EXCURSION_DOUBT]
    if order:
        moves = "; ".join(_excursion(model, cal, z, k, param_name) for k in order[:3])
        files = " and the ".join(
            name
            for name, mask in (("robot file", ~model.setup_mask), ("setup", model.setup_mask))
            if mask[order].any()
        )
        messages.append(WARNINGS["excursion"].format(moves=moves, files=files))
    return messages


def _refusal(
    model: MeasurementModel,
    cal: Calibration,
    test: NoiseTest,
    z: np.ndarray,
    fit: ErrorMetrics,
    robot: RobotFile,
    notes: tuple[str, ...],
) -> str | None:
    """The one line refusing a fit the evidence says is not of this robot and setup; None if not."""
    n, k = len(model.samples), len(cal.downweighted)
    far = z >= EXCURSION_OVERWHELMING
    evidence, causes = [], []
    if test.ratio >= OVERWHELMING_RATIO:
        evidence.append(
            f"the residual is {test.ratio:.0f} times the stated noise (train RMSE {fit.rmse_mm:.3f} mm)"
        )
    if k >= MIXED_FRACTION * n and test.ratio_all >= OVERWHELMING_RATIO:
        evidence.append(f"{k} of {n} rows lie hundreds of noise sigmas off the rest")
        causes.append("samples of different sessions (or of a cell that changed) in one set")
    if far.any():
        evidence.append(_excursion(model, cal, z, int(np.argmax(z)), robot.param_name))
        if (far & ~model.setup_mask).any():
            causes.insert(0, f"a wrong robot model (the robot file describes the {robot.name})")
        if (far & model.setup_mask).any():
            causes.append("a wrong setup file")
    if not evidence:
        return None
    cause = notes[0] if notes else causes[0] if causes else "a wrong robot model or setup, or sessions mixed"
    return WARNINGS["refusal"].format(evidence="; ".join(evidence), cause=cause)


def _wild(model: MeasurementModel, cal: Calibration) -> str | None:
    """The warning naming wild rows (``WILD_FACTOR``), judged before calibration; None if none."""
    errors = np.abs(model.row_error_mm(cal.before.x))
    rows = wild_rows(errors, WILD_FACTOR)
    if rows.size == 0:
        return None
    median = float(np.median(errors))
    return WARNINGS["wild"].format(
        rows=("row " if rows.size == 1 else "rows ") + ", ".join(str(r) for r in rows[:10]),
        ratio=errors[rows].max() / median,
        worst=errors[rows].max(),
        median=median,
        these="that row" if rows.size == 1 else "these rows",
    )


def _excursion(
    model: MeasurementModel, cal: Calibration, z: np.ndarray, k: int, param_name=lambda name: name
) -> str:
    """``J5.d_mm moved 1262 mm from the robot file's value, 1262 times its tolerance (1 mm)``, the
    parameter named as the robot file does (``param_name``)."""
    factor, unit = display_unit(model.names[k])
    name = param_name(model.names[k])
    delta = (cal.x[k] - model.x0[k]) * factor
    if model.setup_mask[k]:
        source, what = "setup's", "stated uncertainty"
    else:
        source, what = "robot file's", "tolerance" if k < N_DH else "prior"
    sigma = model.prior_sigma()[k] * factor
    return (
        f"{name} moved {delta:+.4g} {unit} from the {source} value, "
        f"{z[k]:.0f} times its {what} ({sigma:.3g} {unit})"
    )


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
