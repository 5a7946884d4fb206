"""URScript (Universal Robots): ``def station_measurement(): ... end``, joints in rad.

Moves by joint positions (``movej`` to the stand-off, ``movel`` onto the contact and back: the
controller's own kinematics make the straight line between them), so no frame convention between
the model's base frame and the controller's enters. The contact pose stands in a comment (mm, and
the rotation vector in deg). The program takes corrected targets from the station (``station
sample`` corrects the remaining targets once its running calibration has determined the model):
before it moves to target k it reads the RTDE input registers ur_rtde's ``RTDEIOInterface`` writes
(``drivers.robot``: the index plus one in ``input_int_register_42``, 0 for none, joints 1-5 [rad]
in ``input_double_register_42..46``, joint 6 [urad] in ``input_int_register_43``); if the index
names k (read before and after the joints, so a target being rewritten is not taken half), the
contact is those joints and the stand-off moves by the same joint change, else the planned joints.

A sweep plan (a ``pass`` column) is written per pass: ``movej`` to the stand-off of its first
waypoint, ``movel`` onto it at the approach speed, ``sleep`` the dwell, ``movel`` through its
waypoints at the sweep speed (``v`` [m/s]) with blend radius ``r`` [m] at each but the last (which
stops), ``sleep`` the dwell, ``movel`` back to the last waypoint's stand-off. Its waypoints are the
planned joints (no corrected targets: the session streams, it does not stop at each).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.robot import TARGET_INDEX_INPUT, TARGET_JOINT6_INPUT, TARGET_JOINT_INPUTS, URAD
from station.jobs.programs.common import Program, comment_text, each_pass, header, numbers


def paths(out: Path) -> tuple[Path]:
    return (out,)


def write(p: Program) -> tuple[str]:
    """The URScript program of ``p``."""
    if p.m.plan.is_sweep:
        return (_sweep(p),)
    mo = p.motion
    joint_v, joint_a = np.radians(mo.joint_deg_s), np.radians(mo.joint_deg_s2)
    contact, standoff = np.radians(p.contact_deg()), np.radians(p.standoff_deg())
    notes = [
        *header(p, "mm and rotation vector in deg", units="rad"),
        "Corrected targets: station sample writes target k's contact joints to the RTDE input registers",
        f"int {TARGET_INDEX_INPUT} (k + 1, written last; 0: none), "
        f"double {TARGET_JOINT_INPUTS[0]}..{TARGET_JOINT_INPUTS[-1]} (joints 1-5, rad), "
        f"int {TARGET_JOINT6_INPUT} (joint 6, urad);",
        "before target k the program takes them if the index names k (the stand-off moves with them).",
    ]
    lines = [
        *(f"# {comment_text(n)}" for n in notes),
        "def station_measurement():",
        "  set_tcp(p[{:.6f}, {:.6f}, {:.6f}, 0, 0, 0])".format(*(np.asarray(p.robot.tool_mm) / 1000.0)),
        *_CORRECTED,
    ]
    m = p.m
    for k, target, line, skipped in p.targets():
        if skipped:
            lines.append(f"  # target {target} left out: no stand-off within the joint limits")
            continue
        q, q_off = f"[{numbers(contact[k], 6)}]", f"[{numbers(standoff[k], 6)}]"
        lines += [
            f"  # target {target}, line {line}: contact [{numbers(m.pose[k], 3)}], "
            f"approach [{numbers(m.approach[k], 4)}], stand-off {m.distance_mm[k]:g} mm",
            f"  q = station_target({target}, {q})",
            f"  q_off = station_standoff({q_off}, {q}, q)",
            f"  movej(q_off, a={joint_a:.4f}, v={joint_v:.4f})",
            f"  movel(q, a=0.1, v={mo.approach_mm_s / 1000.0:.4f})",
            f"  sleep({mo.dwell_s:g})",
            f"  movel(q_off, a=0.5, v={mo.retreat_mm_s / 1000.0:.4f})",
        ]
    lines += ["end", "station_measurement()", ""]
    return ("\n".join(lines),)


def _sweep(p: Program) -> str:
    """The URScript program of a sweep plan (module notes)."""
    mo = p.motion
    joint_v, joint_a = np.radians(mo.joint_deg_s), np.radians(mo.joint_deg_s2)
    contact, standoff = np.radians(p.contact_deg()), np.radians(p.standoff_deg())
    sweep_v, blend = mo.sweep_mm_s / 1000.0, mo.blend_mm / 1000.0

    def moves(number, line, rows) -> list[str]:
        first, last = rows[0], rows[-1]
        return [
            f"  # pass {number}, line {line}: {len(rows)} waypoints, targets {p.m.plan.target[first]}.."
            f"{p.m.plan.target[last]}, from [{numbers(p.m.pose[first], 3)}]",
            f"  #   to [{numbers(p.m.pose[last], 3)}]",
            f"  movej([{numbers(standoff[first], 6)}], a={joint_a:.4f}, v={joint_v:.4f})",
            f"  movel([{numbers(contact[first], 6)}], a=0.1, v={mo.approach_mm_s / 1000.0:.4f})",
            f"  sleep({mo.dwell_s:g})",
            *(
                f"  movel([{numbers(contact[k], 6)}], a=0.5, v={sweep_v:.4f}"
                + (f", r={blend:.4f})" if k != last else ")")
                for k in rows[1:]
            ),
            f"  sleep({mo.dwell_s:g})",
            f"  movel([{numbers(standoff[last], 6)}], a=0.5, v={mo.retreat_mm_s / 1000.0:.4f})",
        ]

    return "\n".join(
        [
            *(f"# {comment_text(n)}" for n in header(p, "mm and rotation vector in deg", units="rad")),
            "def station_sweep():",
            "  set_tcp(p[{:.6f}, {:.6f}, {:.6f}, 0, 0, 0])".format(*(np.asarray(p.robot.tool_mm) / 1000.0)),
            *each_pass(
                p, "  # pass {number} left out: no stand-off within the joint limits at an end", moves
            ),
            "end",
            "station_sweep()",
            "",
        ]
    )


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
