"""Corrected targets during a session: the joints at which the running calibration's model puts the
TCP on each planned contact pose, so a running program lands the remaining targets on the edge.

The same maths as ``station compensate`` (``calib.compensation.compensate``): a plan row's contact
pose is the nominal model's TCP pose at its joints (``station plan`` writes the plan's
``x_mm..rz_deg`` so), and its corrected joints are where the calibrated model reaches that pose,
found by damped Newton from the planned joints; a row that cannot be corrected (a joint limit, the
wrist singularity, a large move) keeps its planned joints and is not corrected.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.compensation import Status, compensate
from calib.robot_model import RobotModel
from station.formats.tables import RobotFile
from station.jobs.running import Refit


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


def correct_targets(robot: RobotFile, fit: Refit, plan_q_deg: np.ndarray) -> TargetCorrection:
    """The corrected joints of plan rows ``plan_q_deg`` (M, 6) [deg] written with ``robot``'s
    nominal model, for the robot as ``fit`` models it (see the module notes)."""
    comp = compensate(robot.model(), calibrated_model(robot, fit), np.radians(plan_q_deg))
    return TargetCorrection(fit.n, np.degrees(comp.q), comp.status == Status.OK, comp.shift)
