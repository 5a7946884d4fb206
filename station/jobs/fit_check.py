"""The fit's checks and advice, apart from the pipeline that fits (``station.jobs.calibration``):
how a calibration agrees with the stated noise and tolerances (``fit_check``: a verdict, its
warnings, a refusal naming the likely cause), the report's warnings (``WARNINGS``) and what to do
next (``next_step``, ``NEXT``), and what a hold-out figure can speak for (``HOLDOUT_SCOPES``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from calib.calibrate import Calibration, CalibrationOptions, robust_weights
from calib.consistency import NoiseTest, excursions, neighbour_agreement, noise_test, wild_rows
from calib.kinematics import N_DH
from calib.models import MeasurementModel
from calib.params import display_unit
from station.formats.tables import RobotFile
from station.jobs import absorbed
from station.jobs.report import ErrorMetrics, FitCheck, WorkspacePrediction

WORKSPACE_WARNING_RATIO, WORKSPACE_WARNING_FLOOR_MM = 10.0, 0.5
"""Warn when the predicted workspace error exceeds both this many times the training fit and this."""
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
    nominal_q: np.ndarray | None = None,
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
    prediction whose 95 % bound does not beat the nominal table's expected error over the
    configurations ``nominal_q`` [rad] (N, 6) is refused."""
    r = model.residuals(cal.x)
    options = CalibrationOptions() if lm else CalibrationOptions(loss="linear")
    weights = robust_weights(r, model.groups, cal.scale, options)
    found = absorbed.findings(model, cal, weights)
    nominal = None if workspace is None or nominal_q is None else absorbed.nominal_rmse(model, cal, nominal_q)
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
