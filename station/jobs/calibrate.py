"""From validated files to a calibration and back: builds the measurement model, runs ``calib``,
and turns its arrays into the contract's report and corrected table (display units)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from calib.accuracy import (
    predicted_workspace_rmse,
    workspace_error_modes,
    workspace_rmse_bound,
)
from calib.baselines import BASELINES, BaselineOptions, run_method
from calib.calibrate import Calibration, CalibrationOptions, WithPrior, calibrate, covariance, prepare
from calib.metrics import error_metrics
from calib.models import (
    GROUP_PRIOR,
    N_DH,
    DrawstringFrame,
    DrawstringLineModel,
    DrawstringSamples,
    DrawstringSetup,
)
from calib.observability import MCSResult, select_configurations
from calib.params import DH_NAMES, dh_from_degrees, dh_to_degrees, display_factor
from calib.position import PositionModel, PositionSamples
from errors import InputError
from station.formats.samples import Samples
from station.formats.tables import RobotFile, SetupFile

METHODS = BASELINES + ("lmlc", "mcs-lmlc")
WORKSPACE_POSES = 1000


@dataclass
class Outcome:
    """A finished calibration: the contract's report and the corrected robot table (both dicts)."""

    report: dict
    table: dict
    calibration: Calibration


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
        dial_axis={ln.id: _unit(ln.dial_axis) for ln in setup.lines if ln.dial_axis is not None},
        default_dial_axis=None if default_axis is None else _unit(default_axis),
        rho=setup.rho,
    )


def build_model(samples: Samples, robot: RobotFile, setup: SetupFile | None, setup_where: str):
    """The measurement model for a training set: a position set (tracker) starts its probe offset at
    the robot file's ``tool_mm``; a drawstring set needs the setup file."""
    dh0 = dh_from_degrees(robot.table_deg())
    if samples.kind == "position":
        return PositionModel(_model_samples(samples), dh0, np.array(robot.tool_mm))
    if setup is None:
        raise InputError(f"{samples.path}: a drawstring set needs --setup")
    ds_setup = drawstring_setup(setup, setup_where)
    data = _model_samples(samples)
    frame = DrawstringFrame.from_nominal(data, ds_setup, dh0, robot.tool_mm)
    return DrawstringLineModel(data, ds_setup, frame, dh0, robot.tool_mm)


def run(
    samples: Samples,
    robot: RobotFile,
    setup: SetupFile | None,
    *,
    setup_where: str = "setup",
    holdout: Samples | None = None,
    method: str = "lmlc",
    select: int | None = None,
) -> Outcome:
    """Calibrate on ``samples`` and evaluate before/after on training and ``holdout`` rows.
    ``mcs-lmlc`` first selects ``select`` configurations (default: where O1 flattens)."""
    t0 = time.perf_counter()
    model = build_model(samples, robot, setup, setup_where)
    check_enough(samples, model)
    mcs, optimum = None, None
    if select is not None and method != "mcs-lmlc":
        raise InputError(f"--select {select}: selecting configurations needs --method mcs-lmlc")
    if select is not None and not len(model.names) - len(model.gauges()) <= select <= len(samples):
        unknowns = len(model.names) - len(model.gauges())
        raise InputError(
            f"--select {select}: must lie between the {unknowns} unknowns and the {len(samples)} samples"
        )
    if method == "mcs-lmlc":
        mcs = select_measurements(model, select)
        cal = calibrate(model.with_samples(_subset(samples, mcs.selection.rows)), CalibrationOptions())
    elif method in BASELINES:
        cal, optimum = baseline(model, method)
    else:
        cal = calibrate(model, CalibrationOptions())
    elapsed = time.perf_counter() - t0
    hold_model = holdout_model(model, holdout)
    report = {
        "kind": samples.kind,
        "method": method,
        "before": metrics(model, hold_model, cal.before.x),
        "after": metrics(model, hold_model, cal.x),
        **_setup_unknowns(model, cal.x),
        "identified": [n for n in DH_NAMES if cal.identified[DH_NAMES.index(n)]],
        "held": [{"param": p, "reason": r} for p, r in cal.held.items()],
        "parameters": _parameters(cal),
        "downweighted": [int(r) for r in cal.downweighted],
        "workspace": predicted_workspace(robot, cal),
        "warnings": [],
        "iterations": int(cal.after.nit),
        "time_s": round(elapsed, 4),
    }
    if mcs is not None:
        report["selection"] = {
            "rows": mcs.selection.rows.tolist(),
            "n": int(mcs.n_select),
            "index": "O1",
            "value": mcs.selection.value,
        }
        report["downweighted"] = [int(mcs.selection.rows[r]) for r in cal.downweighted]
    report["warnings"] = warnings(report, model) + short_of_optimum(model, cal.x, optimum, method)
    return Outcome(report, corrected_table(robot, cal, samples, method), cal)


def baseline(model, method: str) -> tuple[Calibration, np.ndarray]:
    """One of the paper's other calibrators (``calib.baselines``) from the pipeline's common start
    and identified parameters; its uncertainty from the Jacobian at its own solution, with the
    noise LMLC fitted. Nothing is down-weighted: these methods have no robust loss. Also returns
    LMLC's solution, the optimum it is judged against."""
    start = calibrate(model, CalibrationOptions())
    found = run_method(method, model, start.before.x, start.identified, BaselineOptions())
    prior = WithPrior(model, model.x0)
    noise = np.where(prior.groups == GROUP_PRIOR, 1.0, start.scale[prior.groups])
    cov, table_cov = covariance(prior, found.x, start.identified, 1.0 / noise)
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
        table_covariance=table_cov,
        downweighted=np.array([], int),
    )
    return cal, start.x


def short_of_optimum(model, x: np.ndarray, optimum: np.ndarray | None, method: str) -> list[str]:
    """A warning when a method stopped well short of the least-squares optimum: its sigmas and
    predicted workspace error describe the optimum, not where it stopped."""
    if optimum is None:
        return []
    rms, best = (float(np.sqrt(np.mean(model.residuals(v) ** 2))) for v in (x, optimum))
    if rms <= 1.5 * best:
        return []
    return [
        f"{method} stopped short of the least-squares optimum (whitened residual RMS {rms:.2f} against "
        f"{best:.2f} for lmlc): its table is worse than the data allows and the predicted workspace "
        "error does not apply to it"
    ]


def select_measurements(model, n_select: int | None) -> MCSResult:
    """MCS at the setup fit: the identified table's observability, setup unknowns projected out."""
    prep = prepare(model)
    _, jac = model.residuals_and_jacobian(prep.before.x)
    line = getattr(model.samples, "line", np.zeros(len(model.samples), int))
    return select_configurations(
        jac, model.rows, prep.free, line, np.random.default_rng(0), n_select=n_select
    )


def _subset(samples: Samples, rows: np.ndarray):
    return _model_samples(
        dataclasses.replace(
            samples,
            q_deg=samples.q_deg[rows],
            measured=samples.measured[rows],
            dial_mm=samples.dial_mm[rows],
            line=samples.line[rows],
        )
    )


def predicted_workspace(robot: RobotFile, cal: Calibration) -> dict:
    """The report's ``workspace``: expected RMS TCP error [mm] over random configurations within
    the joint limits, and the RMS one calibration stays below with 95 % probability."""
    limits = np.radians(robot.limits_deg())
    q = np.random.default_rng(0).uniform(limits[:, 0], limits[:, 1], (WORKSPACE_POSES, 6))
    dh = cal.x[:N_DH].reshape(6, 4)
    modes = workspace_error_modes(dh, np.asarray(robot.tool_mm), q, cal.table_covariance)
    return {
        "predicted_rmse_mm": predicted_workspace_rmse(modes),
        "predicted_rmse_95_mm": workspace_rmse_bound(modes, 0.95),
        "configurations": WORKSPACE_POSES,
    }


def warnings(report: dict, model) -> list[str]:
    """Say when the samples fit well but cannot deliver that accuracy over the workspace."""
    fit = report["after"]["train"]["rmse_mm"]
    predicted = report["workspace"]["predicted_rmse_mm"]
    bound = report["workspace"]["predicted_rmse_95_mm"]
    if predicted <= max(10 * fit, 0.5):
        return []
    directions = np.array([ln["direction"] for ln in report["lines"]])
    suggestion = _new_direction(directions)
    where = "its own line" if len(directions) == 1 else f"its own {len(directions)} lines"
    return [
        f"fits {where} to {fit:.3f} mm; predicted workspace error {predicted:.2f} mm (up to {bound:.2f} mm, "
        "95 %); add a line placement "
        f"along [{suggestion[0]:.2f}, {suggestion[1]:.2f}, {suggestion[2]:.2f}] (base frame), "
        "elsewhere in the workspace and with varied tool orientations"
    ]


def _new_direction(directions: np.ndarray) -> np.ndarray:
    """A unit direction least aligned with every present line direction (perpendicular to all of
    them while there are fewer than three)."""
    if directions.size == 0:
        return np.array([1.0, 0.0, 0.0])
    return np.linalg.svd(directions)[2][-1]


def corrected_table(robot: RobotFile, cal: Calibration, samples: Samples, method: str) -> dict:
    """The robot file with the calibrated table, per-joint sigmas and provenance."""
    table = dh_to_degrees(cal.x[:N_DH].reshape(6, 4))
    factor = display_factor(DH_NAMES)
    sigma = (cal.sigma[:N_DH] * factor).reshape(6, 4)
    joints = []
    for j, joint in enumerate(robot.joints):
        entry = joint.model_dump(exclude={"sigma"})
        entry.update(theta_deg=table[j, 0], d_mm=table[j, 1], a_mm=table[j, 2], alpha_deg=table[j, 3])
        cols = ("theta_deg", "d_mm", "a_mm", "alpha_deg")
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


def _model_samples(s: Samples) -> DrawstringSamples | PositionSamples:
    if s.kind == "position":
        return PositionSamples(np.radians(s.q_deg), s.measured)
    return DrawstringSamples(np.radians(s.q_deg), s.measured, s.dial_mm, s.line)


def _row_errors(model, x) -> np.ndarray:
    """The contract's per-row error [mm]: drawstring ``Y - Y_model``, position ``|m - p_model|``."""
    if isinstance(model, PositionModel):
        return model.position_error_mm(x)
    return model.length_error_mm(x)


def check_enough(samples: Samples, model) -> None:
    """Bad input unless there are at least as many samples as unknowns."""
    unknowns = len(model.names) - len(model.gauges())
    if len(samples) < unknowns:
        raise InputError(
            f"{samples.path}: {len(samples)} samples cannot determine {unknowns} unknowns "
            f"(table and setup): measure at least {unknowns}"
        )


def holdout_model(model, holdout: Samples | None):
    """The training ``model`` (its frame and setup) on the hold-out rows; None without them."""
    return model.with_samples(_model_samples(holdout)) if holdout is not None else None


def metrics(model, hold_model, x) -> dict:
    """The contract's ``{"train": M, "holdout": M}`` of parameters ``x`` (holdout only with rows)."""
    out = {"train": error_metrics(_row_errors(model, x))}
    if hold_model is not None:
        out["holdout"] = error_metrics(_row_errors(hold_model, x))
    return out


def _setup_unknowns(model, x) -> dict:
    if isinstance(model, PositionModel):
        rot, t = model.tracker_from_base(x)
        return {
            "tracker_from_base": {"rotation": rot.tolist(), "translation_mm": t.tolist()},
            "probe_mm": model.probe(x).tolist(),
        }
    lines = []
    for lid in model.line_ids:
        point, direction = model.line(x, lid)
        lines.append({"id": lid, "point_mm": point.tolist(), "direction": direction.tolist()})
    return {"anchor_mm": model.anchor(x).tolist(), "length_offset_mm": model.length_offset(x), "lines": lines}


def _parameters(cal: Calibration) -> dict:
    factor = display_factor(cal.names)
    return {
        name: {"value": float(cal.x[k] * factor[k]), "sigma": float(cal.sigma[k] * factor[k])}
        for k, name in enumerate(cal.names[:N_DH])
        if cal.identified[k]
    }


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)
