"""Corrected targets during a session: the joints at which the running calibration's model puts the
TCP on each planned contact pose, so a running program lands the remaining targets on the edge.

A plan row's contact pose is the nominal model's TCP pose at its joints (``station plan`` writes the
plan's ``x_mm..rz_deg`` so), in the frame the setup's lines were measured in. The calibrated model
lives in a frame of its own, millimetres from that one (``calib.registration``): the fitted lines
register it, and a target on a line the fit has placed is moved onto that fitted line (across it,
the tool's orientation kept), a target elsewhere is the contact pose carried over. The corrected
joints are where the calibrated model reaches that pose, by ``station compensate``'s maths
(``calib.compensation.compensate``, damped Newton from the planned joints); a row that cannot be
corrected (a joint limit, the wrist singularity, a large move) keeps its planned joints.

Offline (a controller without a target channel: ``station program PLAN --table T``), the corrected
table stands for the refit: each contact pose is reached by the table's model from the planned
joints, as ``station compensate`` does (the table's frame is the nominal's up to the base fit the
calibration held), and the targets a first pass left unmeasured go first.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from calib.calibrate import hold_robot
from calib.compensation import CompensationOptions, Status
from calib.registration import register_lines
from calib.residual_map import ResidualMap
from calib.robot_model import RobotModel
from station.formats.plan import Plan
from station.formats.samples import Samples
from station.formats.tables import RobotFile, SetupFile
from station.jobs.compensate import mapped_compensation
from station.jobs.residual_map import fit_table_map, mapped_q_deg
from station.jobs.running import Refit
from station.jobs.verification import table_held

SESSION_MAP_ROWS = 60
"""A running calibration's rows from which its corrected targets add the residual map's prediction:
fewer rarely show a held-out gain, and every judged refit would pay the map's fit (the worker
shares the machine with the session)."""


@dataclass(frozen=True)
class TargetCorrection:
    """Every plan row's corrected joints ``q_deg`` (M, 6) [deg] by the refit on the first ``n``
    samples, whether each could be corrected ``ok`` (M,), and how far the nominal model sees the
    contact move, ``shift_mm`` (M,) [mm] (the robot's error there, as the refit sees it)."""

    n: int
    q_deg: np.ndarray
    ok: np.ndarray
    shift_mm: np.ndarray


def calibrated_model(robot: RobotFile, fit: Refit) -> RobotModel:
    """The robot as the refit ``fit`` models it: its table, the robot file's TCP and limits, and the
    joint-space terms it fitted."""
    model = fit.model
    return RobotModel(
        model.dh(fit.x),
        np.asarray(robot.tool_mm, float),
        np.radians(robot.limits_deg()),
        model.terms,
        model.term_values(fit.x),
    )


def fitted_lines(setup: SetupFile, fit: Refit) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The lines the refit placed (point [mm], unit direction; calibrated frame), by id."""
    return {lid: fit.model.line(fit.x, lid) for lid in getattr(fit.model, "line_ids", [])}


def cell_from_calibrated(setup: SetupFile, fitted: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(R, t)`` taking the calibrated frame to the setup's (``calib.registration``) through the
    fitted lines the setup places (``point_mm``, ``direction``); none: the identity."""
    if not fitted:
        return np.eye(3), np.zeros(3)
    placed = {ln.id: ln for ln in setup.lines if ln.point_mm is not None and ln.direction is not None}
    ids = [lid for lid in fitted if lid in placed]
    if not ids:
        return np.eye(3), np.zeros(3)
    return register_lines(
        np.array([fitted[lid][0] for lid in ids]),
        np.array([fitted[lid][1] for lid in ids]),
        np.array([placed[lid].point_mm for lid in ids], float),
        np.array([placed[lid].direction for lid in ids], float),
        np.array([placed[lid].length_mm for lid in ids], float),
    )


def correct_targets(
    robot: RobotFile, setup: SetupFile, fit: Refit, plan_q_deg: np.ndarray, plan_lines: np.ndarray
) -> TargetCorrection:
    """The corrected joints of plan rows ``plan_q_deg`` (M, 6) [deg] on lines ``plan_lines`` (M,),
    written with ``robot``'s nominal model, for the robot as ``fit`` models it (module notes), plus
    the residual map of the refit's rows where they show one (``station.jobs.residual_map``; from
    ``SESSION_MAP_ROWS`` rows on): of their residuals alone, not the angle errors fitted beside the
    table (which, on a refit that still moves, moved the demo's targets: true error 0.05 -> 0.067
    mm)."""
    calibrated = calibrated_model(robot, fit)
    found = fit_table_map(fit.model, fit.x, None)[0] if fit.n >= SESSION_MAP_ROWS else None
    fitted = fitted_lines(setup, fit)
    return TargetCorrection(
        fit.n, *_corrected(robot, setup, calibrated, fitted, plan_q_deg, plan_lines, found)
    )


def _corrected(
    robot,
    setup,
    calibrated: RobotModel,
    fitted: dict,
    plan_q_deg,
    plan_lines,
    residual_map=None,
    meant_pose=None,
):
    """The joints (M, 6) [deg] at which ``calibrated`` (plus its ``residual_map``'s prediction)
    reaches each plan row's contact pose (``meant_pose`` (M, 6: mm, rotation vector deg), else
    ``robot``'s nominal TCP at the planned joints; the setup's frame), carried into its frame
    through the ``fitted`` lines and onto them; whether each was corrected (M,) and how far the
    nominal model sees it move (M,) [mm]."""
    nominal = robot.model()
    q0 = np.radians(plan_q_deg)
    if meant_pose is None:
        p, rot = nominal.tool_frames(q0)
    else:
        p, rot = meant_pose[:, :3], Rotation.from_rotvec(meant_pose[:, 3:], degrees=True).as_matrix()
    r_cell, t_cell = cell_from_calibrated(setup, fitted)
    p_cal, rot_cal = (p - t_cell) @ r_cell, np.einsum("ji,njk->nik", r_cell, rot)
    for lid, (point, direction) in fitted.items():  # onto the line the fit placed
        rows = np.asarray(plan_lines) == lid
        p_cal[rows] = point + np.outer((p_cal[rows] - point) @ direction, direction)
    comp = mapped_compensation(nominal, calibrated, q0, CompensationOptions(), residual_map, (p_cal, rot_cal))
    return np.degrees(comp.q), comp.status == Status.OK, comp.shift


def table_lines(
    table: RobotFile, setup: SetupFile, samples: Samples, residual_map: ResidualMap | None = None
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """The gauge lines (point [mm], unit direction) by id as ``samples`` place them in ``table``'s
    frame (plus its ``residual_map``'s prediction): the setup unknowns fitted with the table held,
    as ``station verify`` fits them."""
    judged = replace(samples, q_deg=mapped_q_deg(residual_map, samples.q_deg))
    model, x0 = table_held(judged, table, setup, "setup")
    fit = hold_robot(model, x0)[1]
    return {lid: model.line(fit.x, lid) for lid in getattr(model, "line_ids", [])}


def offline_correction(
    plan: Plan,
    nominal: RobotFile,
    table: RobotFile,
    setup: SetupFile | None,
    samples: Samples | None,
    residual_map: ResidualMap | None = None,
) -> TargetCorrection:
    """The joints at which the corrected ``table`` (plus its ``residual_map``'s prediction) puts
    the TCP on each of ``plan``'s contact poses
    (its ``x_mm..rz_deg``, else the ``nominal`` model's TCP at the planned joints), from the
    planned joints; with the first pass's ``samples`` (and its ``setup``), carried into the table's
    frame through the lines they place (else the table's frame taken for the setup's); ``n``: the
    samples the table was calibrated on (0 if it does not say)."""
    fitted = {} if samples is None or setup is None else table_lines(table, setup, samples, residual_map)
    calibrated = table.model()
    found = _corrected(nominal, setup, calibrated, fitted, plan.q_deg, plan.line, residual_map, plan.pose)
    return TargetCorrection(int((table.calibration or {}).get("n_samples", 0)), *found)


def unmeasured_first(plan: Plan, measured) -> tuple[Plan, int]:
    """``plan`` reordered with the targets whose ids are not in ``measured`` first (each group in
    plan order), and how many those are."""
    done = np.isin(plan.target, np.fromiter(measured, int))
    order = np.concatenate([np.flatnonzero(~done), np.flatnonzero(done)])
    return plan.take(order), int((~done).sum())
