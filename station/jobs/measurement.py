"""``station program``: the measurement program that brings the tool onto each planned contact.

Per target: a joint move to a stand-off pose ``standoff_mm`` back along the approach, a slow linear
approach to the contact pose, a dwell the station captures in, a linear retreat to the stand-off.
The contact poses are the nominal model's (the plan's ``x_mm..rz_deg``, or, in a plan written
before them, the nominal TCP at its joints): on a real robot the tool lands off the edge by the
robot's error, which the dial reads and its gate judges. ``urscript`` moves by joint positions
(the controller's own kinematics make the straight line between them), so no frame convention
between this base frame and the controller's enters; ``poses-csv`` lists every pose and joint set
for any other controller (position, rotation vector, quaternion).

The URScript takes corrected targets from the station (``station sample`` corrects the remaining
targets once its running calibration has determined the model): before it moves to target k it
reads the RTDE input registers ur_rtde's ``RTDEIOInterface`` writes (``drivers.robot``: the index
plus one in ``input_int_register_42``, 0 for none, joints 1-5 [rad] in
``input_double_register_42..46``, joint 6 [urad] in ``input_int_register_43``); if the index names
k (read before and after the joints, so a target being rewritten is not taken half), the contact
is those joints and the stand-off moves by the same joint change, else the planned joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib import ik
from drivers.robot import TARGET_INDEX_INPUT, TARGET_JOINT6_INPUT, TARGET_JOINT_INPUTS, URAD
from errors import InputError
from station.formats.plan import APPROACH_COLUMNS, POSE_COLUMNS, Plan
from station.formats.samples import Q_COLUMNS
from station.formats.tables import RobotFile
from station.jobs.planning import contact_poses, robot_arrays

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
    retreat speeds [mm/s], the joint moves' speed [deg/s] and acceleration [deg/s^2]."""

    standoff_mm: float = 20.0
    dwell_s: float = 3.0
    approach_mm_s: float = 5.0
    retreat_mm_s: float = 50.0
    joint_deg_s: float = 30.0
    joint_deg_s2: float = 60.0


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


def urscript(m: Measurement, robot: RobotFile, source: str, motion: Motion = Motion()) -> str:
    """A URScript program (``def station_measurement(): ... end``) for the measurement ``m``."""
    deg = np.radians
    joint_v, joint_a = deg(motion.joint_deg_s), deg(motion.joint_deg_s2)
    lines = [
        f"# Measurement program for {program_text(robot.name)}: {len(m.plan)} targets from "
        f"{program_text(source)} (station program).",
        f"# Per target: movej to a stand-off {motion.standoff_mm:g} mm back along the approach, movel at "
        f"{motion.approach_mm_s:g} mm/s onto the contact pose,",
        f"# a {motion.dwell_s:g} s dwell (station sample captures there), movel back to the stand-off. "
        "Joints in rad; poses (comments) in mm/deg, base frame.",
        "# The contact poses are the nominal model's: the dial reads how far the real tool lands off it.",
        "# Corrected targets: station sample writes target k's contact joints to the RTDE input registers",
        f"# int {TARGET_INDEX_INPUT} (k + 1, written last; 0: none), "
        f"double {TARGET_JOINT_INPUTS[0]}..{TARGET_JOINT_INPUTS[-1]} (joints 1-5, rad), "
        f"int {TARGET_JOINT6_INPUT} (joint 6, urad);",
        "# before target k the program takes them if the index names k (the stand-off moves with them).",
        "def station_measurement():",
        "  set_tcp(p[{:.6f}, {:.6f}, {:.6f}, 0, 0, 0])".format(*(np.asarray(robot.tool_mm) / 1000.0)),
        *_CORRECTED,
    ]
    for k in range(len(m.plan)):
        q, q_off = deg(m.plan.q_deg[k]), deg(m.standoff_q_deg[k])
        target = int(m.plan.target[k])
        if m.skipped[k]:
            lines.append(f"  # target {target} left out: no stand-off within the joint limits")
            continue
        lines += [
            f"  # target {target}, line {int(m.plan.line[k])}: contact "
            f"{_numbers(m.pose[k], 3)}, approach {_numbers(m.approach[k], 4)}, "
            f"stand-off {m.distance_mm[k]:g} mm",
            f"  q = station_target({target}, {_numbers(q, 6)})",
            f"  q_off = station_standoff({_numbers(q_off, 6)}, {_numbers(q, 6)}, q)",
            f"  movej(q_off, a={joint_a:.4f}, v={joint_v:.4f})",
            f"  movel(q, a=0.1, v={motion.approach_mm_s / 1000.0:.4f})",
            f"  sleep({motion.dwell_s:g})",
            f"  movel(q_off, a=0.5, v={motion.retreat_mm_s / 1000.0:.4f})",
        ]
    lines += ["end", "station_measurement()", ""]
    return "\n".join(lines)


_INDEX = f"read_input_integer_register({TARGET_INDEX_INPUT})"
_CORRECTED = (
    "  def station_target(k, q):",
    "    # target k's contact joints: the station's corrected ones if the registers name k, else q",
    f"    if {_INDEX} == k + 1:",
    "      c = ["
    + ", ".join(f"read_input_float_register({r})" for r in TARGET_JOINT_INPUTS)
    + f", read_input_integer_register({TARGET_JOINT6_INPUT}) / {URAD:.1f}]",
    f"      if {_INDEX} == k + 1:",
    "        return c",
    "      end",
    "    end",
    "    return q",
    "  end",
    "  def station_standoff(q_off, q, c):",
    "    # the stand-off moved by the contact's joint change",
    "    return [" + ", ".join(f"q_off[{i}] + c[{i}] - q[{i}]" for i in range(6)) + "]",
    "  end",
)
"""The URScript functions that take a corrected target (module notes)."""


POSES_COLUMNS = (
    "target",
    "line",
    *POSE_COLUMNS,
    "qw",
    "qx",
    "qy",
    "qz",
    *APPROACH_COLUMNS,
    "standoff_x_mm",
    "standoff_y_mm",
    "standoff_z_mm",
    *Q_COLUMNS,
    *(f"standoff_{c}" for c in Q_COLUMNS),
    "dwell_s",
)


def poses_csv(m: Measurement, motion: Motion = Motion()) -> str:
    """One row per target (``POSES_COLUMNS``): the contact pose (position, rotation vector and
    quaternion w, x, y, z), the approach, the stand-off position, both joint sets, the dwell."""
    quat = Rotation.from_rotvec(m.pose[:, 3:], degrees=True).as_quat()[:, [3, 0, 1, 2]]
    out = [",".join(POSES_COLUMNS)]
    for k in np.flatnonzero(~m.skipped):
        cells = [
            str(int(m.plan.target[k])),
            str(int(m.plan.line[k])),
            *(f"{v:.4f}" for v in m.pose[k]),
            *(f"{v:.8f}" for v in quat[k]),
            *(f"{v:.6f}" for v in m.approach[k]),
            *(f"{v:.4f}" for v in m.standoff_mm[k]),
            *(f"{v:.6f}" for v in m.plan.q_deg[k]),
            *(f"{v:.6f}" for v in m.standoff_q_deg[k]),
            f"{motion.dwell_s:g}",
        ]
        out.append(",".join(cells))
    return "\n".join(out) + "\n"


def program_text(text: str) -> str:
    """``text`` as it may stand in a program's comment or string, in any controller's language:
    every character outside printable ASCII escaped (``\\n``, ``\\x1b``, ``\\u00e9``), so that
    a robot's or a file's name with a line break cannot start a line of code."""
    return "".join(c if " " <= c <= "~" and c != "\\" else c.encode("unicode_escape").decode() for c in text)


def _numbers(v, digits: int) -> str:
    return "[" + ", ".join(f"{x:.{digits}f}" for x in v) + "]"
