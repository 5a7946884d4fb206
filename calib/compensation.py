"""Program compensation: the joints at which the calibrated robot reaches what the program meant.

A program row is a configuration ``q_0`` written with the nominal model; the pose it means is the
nominal model's TCP pose there, ``(p_nom(q_0), R_nom(q_0))``. Its compensation is the configuration
``q`` near ``q_0`` at which the calibrated model reaches that same pose::

    p_cal(q) = p_nom(q_0),    R_cal(q) = R_nom(q_0)

solved for all rows at once by damped Newton from ``q_0`` itself (``ik.solve_pose``; steps are cut
so a row moves continuously and keeps its branch). Matching the whole pose makes the result the
same for any tool rigidly fixed to the flange. A row keeps its own joints, with a status saying
why, when its joints are outside the limits, when it lies within ``wrist_margin`` of the wrist
singularity (there a small tool correction turns joints 4 and 6 by a lot), when Newton does not
reach the pose to ``position_tol`` / ``orientation_tol``, when the compensated joints leave the
limits, or when they move further than ``max_joint_change`` (a different branch, or a singularity
the wrist test does not cover).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from calib.ik import NewtonOptions, solve_pose
from calib.robot_model import RobotModel


class Status(IntEnum):
    """Per-row outcome; every status but ``OK`` keeps the row's own joints."""

    OK = 0
    OUTSIDE_LIMITS = 1
    WRIST_SINGULARITY = 2
    NOT_CONVERGED = 3
    LEAVES_LIMITS = 4
    LARGE_MOVE = 5


@dataclass(frozen=True, kw_only=True)
class CompensationOptions:
    """Thresholds in internal units: ``position_tol`` [mm] and ``orientation_tol`` [rad] that a
    compensated row must reach; ``wrist_margin`` [rad] between the axes of joints 4 and 6;
    ``max_joint_change`` [rad] of any joint; ``newton``: the solver (it stops when every row is
    100x inside the tolerances)."""

    position_tol: float = 1e-3
    orientation_tol: float = np.radians(1e-4)
    wrist_margin: float = np.radians(10.0)
    max_joint_change: float = np.radians(5.0)
    newton: NewtonOptions = field(
        default_factory=lambda: NewtonOptions(
            iterations=20, position_tol=1e-5, orientation_tol=np.radians(1e-6)
        )
    )


@dataclass(frozen=True)
class Compensation:
    """Per program row (N rows): ``q`` (N, 6) [rad] the joints to run (compensated, or the row's
    own where ``status`` (N,) is not OK); ``shift`` (N,) [mm] how far the nominal model, and so the
    controller, sees the TCP move; ``joint_change`` (N,) [rad] the largest joint move the
    compensation asked for; ``position_error`` [mm] / ``orientation_error`` [rad] (N,) left by
    Newton (NaN where not solved); ``model_error`` (N,) [mm] how far the calibrated model puts the
    uncompensated row's TCP from the intended one; ``wrist_angle`` (N,) [rad] at the row's joints;
    ``limit_joint`` (N,) the first joint (0-based) outside its limits, -1 if none, of the row's
    joints or, for ``LEAVES_LIMITS``, of the compensated ones."""

    q: np.ndarray
    status: np.ndarray
    shift: np.ndarray
    joint_change: np.ndarray
    position_error: np.ndarray
    orientation_error: np.ndarray
    model_error: np.ndarray
    wrist_angle: np.ndarray
    limit_joint: np.ndarray


def compensate(
    nominal: RobotModel,
    calibrated: RobotModel,
    q_program: np.ndarray,
    options: CompensationOptions = CompensationOptions(),
    meant: tuple[np.ndarray, np.ndarray] | None = None,
) -> Compensation:
    """Compensate program rows ``q_program`` (N, 6) [rad] written with ``nominal`` for the
    ``calibrated`` robot (both with the same tool). See the module docstring. ``meant``: the poses
    to reach instead of the nominal model's at the rows' joints, positions (N, 3) [mm] and
    orientations (N, 3, 3) in the calibrated model's frame (a frame other than the nominal's)."""
    q0 = np.asarray(q_program, float)
    n = len(q0)
    p_meant, r_meant = nominal.tool_frames(q0) if meant is None else meant
    limit_joint = calibrated.first_outside_limits(q0)
    wrist = calibrated.wrist_angle(q0)
    status = np.full(n, Status.OK, int)
    status[limit_joint >= 0] = Status.OUTSIDE_LIMITS
    status[(status == Status.OK) & (wrist < options.wrist_margin)] = Status.WRIST_SINGULARITY
    rows = np.flatnonzero(status == Status.OK)
    found = solve_pose(
        calibrated.tool_frames, calibrated.jacobian, p_meant[rows], r_meant[rows], q0[rows], options.newton
    )
    q_new = q0.copy()
    q_new[rows] = found.q
    position_error, orientation_error = np.full(n, np.nan), np.full(n, np.nan)
    position_error[rows], orientation_error[rows] = found.position_error, found.orientation_error
    change = np.abs(q_new - q0).max(axis=1)
    leaves = calibrated.first_outside_limits(q_new)
    solved = status == Status.OK
    not_reached = ~((position_error <= options.position_tol) & (orientation_error <= options.orientation_tol))
    status[solved & not_reached] = Status.NOT_CONVERGED
    status[(status == Status.OK) & (leaves >= 0)] = Status.LEAVES_LIMITS
    status[(status == Status.OK) & (change > options.max_joint_change)] = Status.LARGE_MOVE
    limit_joint = np.where(status == Status.LEAVES_LIMITS, leaves, limit_joint)
    ok = status == Status.OK
    q_out = np.where(ok[:, None], q_new, q0)
    p_out = nominal.tool_frames(q_out)[0]
    p_row = p_meant if meant is None else nominal.tool_frames(q0)[0]
    return Compensation(
        q=q_out,
        status=status,
        shift=np.linalg.norm(p_out - p_row, axis=1),
        joint_change=change,
        position_error=position_error,
        orientation_error=orientation_error,
        model_error=np.linalg.norm(calibrated.tool_frames(q0)[0] - p_meant, axis=1),
        wrist_angle=wrist,
        limit_joint=limit_joint,
    )
