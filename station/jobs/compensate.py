"""``station compensate``: a program written with the nominal model, rewritten so the calibrated
robot reaches what it meant; the compensated CSV, a report and a summary."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calib.accuracy import predicted_workspace_rmse, workspace_error_modes, workspace_rmse_bound
from calib.compensation import Compensation, CompensationOptions, Status, compensate
from calib.residual_map import MAPPED_PASSES, ResidualMap, left_share
from calib.robot_model import RobotModel
from station.formats.program import Program
from station.formats.tables import RobotFile


@dataclass(frozen=True)
class Outcome:
    """The compensated program's CSV ``text`` and the ``report`` (a JSON-ready dict)."""

    text: str
    report: dict


def run(
    program: Program,
    table: RobotFile,
    nominal: RobotFile,
    *,
    table_where: str,
    nominal_where: str,
    options: CompensationOptions | None = None,
    residual_map: ResidualMap | None = None,
) -> Outcome:
    """Compensate ``program`` for the calibrated ``table`` (its ``nominal`` model wrote the program)
    and its ``residual_map`` (``mapped_compensation``). The program's joints are the controller's:
    converted to the model's by the nominal robot file's ``[controller]`` on read, and back on
    write."""
    t0 = time.perf_counter()
    calibrated = table.model()
    options = options or CompensationOptions()
    controller = nominal.controller
    q_model = controller.model_deg(program.q_deg)
    comp = mapped_compensation(nominal.model(), calibrated, np.radians(q_model), options, residual_map)
    status = [status_text(comp, i, options, calibrated.limits) for i in range(len(program))]
    q_out = np.where(
        (comp.status == Status.OK)[:, None], controller.controller_deg(np.degrees(comp.q)), program.q_deg
    )
    text = program.csv_text(q_out, comp.shift, status)
    ok = comp.status == Status.OK
    cov = table.covariance(table_where)
    report = {
        "program": program.path,
        "table": table_where,
        "robot": nominal_where,
        "rows": len(program),
        "compensated": int(ok.sum()),
        "kept": int((~ok).sum()),
        "status_counts": {s.name.lower(): int(np.sum(comp.status == s)) for s in Status},
        "shift_mm": _rms_max(comp.shift[ok]),
        "joint_change_deg": {"max": float(np.degrees(comp.joint_change[ok].max(initial=0.0)))},
        "model_error_mm": _rms_max(comp.model_error),
        "predicted": predicted_accuracy(calibrated, comp.q[ok], cov, residual_map),
        **({"map": {"used": True}} if residual_map is not None else {}),
        "flagged": [
            {"row": int(i), "status": status[i], "model_error_mm": float(comp.model_error[i])}
            for i in np.flatnonzero(~ok)
        ],
        "warnings": [] if cov is not None else [NO_COVARIANCE.format(table=table_where)],
        "time_s": round(time.perf_counter() - t0, 4),
    }
    return Outcome(text, report)


NO_COVARIANCE = (
    "{table} carries no covariance ([calibration] covariance, written by station calibrate): "
    "no predicted accuracy"
)


def mapped_compensation(
    nominal: RobotModel,
    calibrated: RobotModel,
    q: np.ndarray,
    options: CompensationOptions,
    residual_map: ResidualMap | None = None,
    meant: tuple[np.ndarray, np.ndarray] | None = None,
) -> Compensation:
    """``calib.compensation.compensate`` of program rows ``q`` (N, 6) [rad] toward the poses
    ``meant`` (default: the nominal model's at ``q``), where the calibrated model plus the
    ``residual_map``'s prediction reach them: the target moved against the prediction at the
    compensated joints, ``MAPPED_PASSES`` times (it changes by micrometres between passes)."""
    comp = compensate(nominal, calibrated, q, options, meant)
    if residual_map is None:
        return comp
    p_meant, r_meant = nominal.tool_frames(q) if meant is None else meant
    for _ in range(MAPPED_PASSES):
        comp = compensate(
            nominal, calibrated, q, options, (p_meant - residual_map.predict(comp.q)[0], r_meant)
        )
    return comp


def predicted_accuracy(
    model, q: np.ndarray, cov: np.ndarray | None, residual_map: ResidualMap | None = None
) -> dict | None:
    """The calibration's expected RMS TCP error [mm] over configurations ``q`` (N, 6) [rad], and the
    RMS one calibration stays below with 95 %, after a rigid re-fit of the base (``calib.accuracy``),
    each configuration's share counted by what the ``residual_map`` leaves there (its variance over
    the table's: ``calib.residual_map.left_share``; 1 far from its rows); None without a
    covariance or with fewer than 3 rows."""
    if cov is None or len(q) < 3:
        return None
    left = None if residual_map is None else left_share(residual_map, q)
    modes = workspace_error_modes(model.dh, model.tool, q, cov, model.terms, left=left)
    return {
        "rmse_mm": predicted_workspace_rmse(modes),
        "rmse_95_mm": workspace_rmse_bound(modes, 0.95),
        "rows": int(len(q)),
    }


def status_text(comp: Compensation, i: int, options: CompensationOptions, limits: np.ndarray) -> str:
    """The ``status`` cell of row ``i``: ``ok``, or ``kept:`` and why the row keeps its joints."""
    code = Status(comp.status[i])
    if code == Status.OK:
        return "ok"
    if code in (Status.OUTSIDE_LIMITS, Status.LEAVES_LIMITS):
        j = int(comp.limit_joint[i])
        lo, hi = np.degrees(limits[j])
        if code == Status.OUTSIDE_LIMITS:
            return f"kept: q{j + 1} outside its limits {lo:g} to {hi:g} deg"
        return f"kept: compensated q{j + 1} would leave its limits {lo:g} to {hi:g} deg"
    if code == Status.WRIST_SINGULARITY:
        return (
            f"kept: axes 4 and 6 {np.degrees(comp.wrist_angle[i]):.1f} deg apart, within the wrist "
            f"singularity margin {np.degrees(options.wrist_margin):g} deg"
        )
    if code == Status.NOT_CONVERGED:
        return (
            f"kept: pose not reached ({comp.position_error[i]:.4f} mm and "
            f"{np.degrees(comp.orientation_error[i]):.5f} deg left)"
        )
    return (
        f"kept: compensation would turn a joint {np.degrees(comp.joint_change[i]):.2f} deg "
        f"(over {np.degrees(options.max_joint_change):g}): near a singularity or another branch"
    )


def summary(report: dict) -> str:
    """What the user reads: rows compensated, how far targets moved, the promise, what was kept."""
    kept = {k: v for k, v in report["status_counts"].items() if k != "ok" and v}
    lines = [
        f"compensated {report['compensated']} of {report['rows']} rows"
        + (
            f"; {report['kept']} kept their joints ("
            + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in kept.items())
            + "; see the status column)"
            if kept
            else ""
        ),
        f"uncompensated, the calibrated model puts the program {report['model_error_mm']['rms']:.3f} mm RMS "
        f"off (max {report['model_error_mm']['max']:.3f})",
        f"targets shifted {report['shift_mm']['rms']:.3f} mm RMS (max {report['shift_mm']['max']:.3f}), "
        f"joints by up to {report['joint_change_deg']['max']:.3f} deg",
    ]
    if "map" in report:
        lines.append(
            "targets compensated for the table plus its residual map (the error it learnt near the rows)"
        )
    if report["predicted"] is not None:
        p = report["predicted"]
        lines.append(
            f"predicted accuracy of the compensated rows: {p['rmse_mm']:.3f} mm RMS (95 %: below "
            f"{p['rmse_95_mm']:.3f} mm), with the base registered"
        )
    lines.append(
        "run the compensated joints as joint targets: the controller's own Cartesian interpolation "
        "(linear moves between them) and poses still use its factory model"
    )
    return "\n".join(lines + [f"warning: {w}" for w in report["warnings"]])


def _rms_max(v: np.ndarray) -> dict:
    if v.size == 0:
        return {"rms": 0.0, "max": 0.0}
    return {"rms": float(np.sqrt(np.mean(v**2))), "max": float(v.max())}
