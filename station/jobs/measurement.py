"""``station program``: the geometry of the measurement program that brings the tool onto each
planned contact (the writers, one per controller language: ``station.jobs.programs``).

Per target: a joint move to a stand-off pose ``standoff_mm`` back along the approach, a slow linear
approach to the contact pose, a dwell the station captures in, a linear retreat to the stand-off.
The contact poses are the nominal model's (the plan's ``x_mm..rz_deg``, or, in a plan written
before them, the nominal TCP at its joints): on a real robot the tool lands off the edge by the
robot's error, which the dial reads and its gate judges. The stand-off keeps the contact's tool
orientation, so the linear moves between them do not turn the tool: every point of it, the flange
as the ball, moves on a straight line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib import ik
from calib.sweep import SweepLimits
from errors import InputError
from station.formats.plan import Plan
from station.formats.tables import RobotFile
from station.jobs.planning import contact_poses, robot_arrays

SWEPT = SweepLimits()
MIN_STANDOFF_MM = 2.0
"""A target near a joint limit gets a shorter stand-off (halved until it fits), not below this."""
POSE_AGREES_MM = 10.0
"""A plan's contact pose this far from the model's TCP at its joints belongs to another robot or tool
(beyond the few mm a robot's own error, or a compensation, moves it)."""
POSE_AGREES_DEG = 3.0
"""A plan's contact orientation this far from the model's tool at its joints disagrees with them
(beyond the fraction of a degree a robot's own error, or a compensation, turns it): the linear
approach onto such a pose would turn the wrist on the way in."""


@dataclass(frozen=True)
class Motion:
    """How the program moves: stand-off distance [mm], dwell at the contact [s], the approach and
    retreat speeds [mm/s], the joint moves' speed [deg/s] and acceleration [deg/s^2], as a share
    of each axis' top speed where a controller sets it so (KRL, Fanuc) [%], and their TCP speed
    where a controller limits them by it (RAPID's speeddata) [mm/s]; along a sweep plan's pass, the
    TCP speed [mm/s] and tool turn rate [deg/s] it was designed for (``calib.sweep.SweepLimits``)
    and the blend radius at its waypoints [mm]."""

    standoff_mm: float = 20.0
    dwell_s: float = 3.0
    approach_mm_s: float = 5.0
    retreat_mm_s: float = 50.0
    joint_deg_s: float = 30.0
    joint_deg_s2: float = 60.0
    joint_percent: float = 10.0
    joint_mm_s: float = 250.0
    sweep_mm_s: float = SWEPT.tcp_mm_s
    sweep_deg_s: float = SWEPT.turn_deg_s
    blend_mm: float = 10.0


@dataclass(frozen=True)
class Measurement:
    """Every target's contact joints ``q_deg`` (M, 6), ``pose`` (M, 6: mm, rotation vector deg) and
    unit ``approach`` (M, 3), and the stand-off pose's joints ``standoff_q_deg``, position
    ``standoff_mm`` (M, 3) and distance back from the contact ``distance_mm`` (M,; NaN: no
    stand-off down to ``MIN_STANDOFF_MM`` within the joint limits, the target left out)."""

    plan: Plan
    pose: np.ndarray
    approach: np.ndarray
    standoff_q_deg: np.ndarray
    standoff_mm: np.ndarray
    distance_mm: np.ndarray

    @property
    def skipped(self) -> np.ndarray:
        """The targets (M,) the program leaves out."""
        return np.isnan(self.distance_mm)


def measurement(plan: Plan, robot: RobotFile, where: str, motion: Motion = Motion()) -> Measurement:
    """The poses and joints of the program for ``plan`` (read from ``where``) on ``robot`` (the
    nominal model, or a corrected table for a plan ``station compensate`` corrected: its stand-offs
    then follow the corrected model too)."""
    q = np.radians(plan.q_deg)
    nominal = contact_poses(robot, q)
    pose = nominal if plan.pose is None else plan.pose
    off = np.linalg.norm(pose[:, :3] - nominal[:, :3], axis=1)
    if np.any(off > POSE_AGREES_MM):
        k = int(np.argmax(off))
        raise InputError(
            f"{where}: target {int(plan.target[k])}: its contact pose lies {off[k]:.1f} mm from "
            f"{program_text(robot.name)}'s TCP at its joints: a plan for another robot or tool (tool_mm)"
        )
    turn = (
        Rotation.from_rotvec(pose[:, 3:], degrees=True)
        * Rotation.from_rotvec(nominal[:, 3:], degrees=True).inv()
    ).magnitude()
    if np.any(np.degrees(turn) > POSE_AGREES_DEG):
        k = int(np.argmax(turn))
        raise InputError(
            f"{where}: target {int(plan.target[k])}: its contact orientation (rx_deg, ry_deg, rz_deg) is "
            f"{np.degrees(turn[k]):.1f} deg from {program_text(robot.name)}'s tool at its joints: the row's "
            "pose and joints disagree (the approach would turn the wrist on the way in)"
        )
    rot = Rotation.from_rotvec(pose[:, 3:], degrees=True).as_matrix()
    approach = rot[:, :, 2] if plan.approach is None else plan.approach
    distance = np.full(len(plan), motion.standoff_mm)
    q_off_deg, bad = _standoff(robot, pose, rot, approach, q, distance)
    while bad.any() and distance[bad].max() / 2 >= MIN_STANDOFF_MM:  # near a joint limit: come in closer
        distance[bad] /= 2
        q_off_deg[bad], bad[bad] = _standoff(robot, pose[bad], rot[bad], approach[bad], q[bad], distance[bad])
    distance[bad] = np.nan  # no stand-off within the limits: the program leaves the target out
    standoff = pose[:, :3] - distance[:, None] * approach
    return Measurement(plan, pose, approach, q_off_deg, standoff, distance)


def _standoff(robot: RobotFile, pose, rot, approach, q, distance) -> tuple[np.ndarray, np.ndarray]:
    """Joints [deg] (N, 6) of the stand-off poses ``distance`` (N,) [mm] back along ``approach``
    from the contacts, by Newton from the contact joints ``q`` [rad], and which (N,) are out of
    reach or beyond the joint limits."""
    dh, tool = robot_arrays(robot)
    target = pose[:, :3] - distance[:, None] * approach
    q_off, err = ik.solve(dh, tool, target, rot, q, iterations=100, damping=1e-6, tol=1e-6)
    q_deg = np.degrees(q_off)
    limits = robot.limits_deg()
    outside = (q_deg < limits[:, 0]) | (q_deg > limits[:, 1])
    return q_deg, (err > 1e-3) | outside.any(axis=1)


def program_text(text: str) -> str:
    """``text`` as it may stand in a program's comment or string, in any controller's language:
    every character outside printable ASCII escaped (``\\n``, ``\\x1b``, ``\\u00e9``), so that
    a robot's or a file's name with a line break cannot start a line of code."""
    return "".join(c if " " <= c <= "~" and c != "\\" else c.encode("unicode_escape").decode() for c in text)
