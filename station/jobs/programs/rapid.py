"""ABB RAPID: ``MODULE StationMeasurement ... ENDMODULE`` with ``PROC station_measurement()``.

Per target two ``CONST jointtarget``s, ``t<target>_off`` (the stand-off) and ``t<target>_on`` (the
contact): ``[[j1, .., j6], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]]`` (deg, the controller's convention; no
external axes), and a call ``station_target t<target>_off, t<target>_on;`` that does ``MoveAbsJ``
to the stand-off, ``MoveL`` onto the contact at the approach speed, ``fine``, ``WaitTime \\InPos``
the dwell, ``MoveL`` back. MoveL needs a robtarget: ``CalcRobT(jointtarget, tool0)`` has the
controller's own kinematics make it from the joints, so its configuration data (``robconf``) and
base frame are the controller's own; declared robtargets would need both from the nominal model,
which knows neither. ``tool0`` (the flange) serves: the linear moves do not turn the tool, so the
ball moves on the same straight line. The contact pose stands in a comment before the call, in
ABB's convention ``[[x, y, z], [q1, q2, q3, q4]]`` (mm; quaternion w, x, y, z) in the nominal
model's base frame (not necessarily the controller's ``wobj0``). Speeds are ``speeddata``
``[v_tcp mm/s, v_ori deg/s, v_leax mm/s, v_reax deg/s]``. No real controller has checked it.

A sweep plan (a ``pass`` column) has a ``CONST jointtarget t<target>_on`` per waypoint and
``t<target>_off`` for the first and last of each pass; per pass ``MoveAbsJ`` to the first's
stand-off, ``MoveL`` onto it at the approach speed, ``fine``, ``WaitTime \\InPos`` the dwell, then
``MoveL`` through the waypoints at ``station_sweep`` (the sweep speed [mm/s] and turn rate
[deg/s]) with zone ``z<blend>`` (``zonedata``: the path's corner radius [mm]) at each but the last,
``fine`` there, the dwell, ``MoveL`` back to its stand-off; those moves with the tool
``station_ball`` (the robot file's ``tool_mm``, no turn: the tool turns along a pass, so the ball,
not the flange, must move on the edge).
"""

from __future__ import annotations

from pathlib import Path

from station.jobs.measurement import program_text
from station.jobs.programs.common import Program, comment_text, each_pass, header, numbers, quaternion_wxyz

BALL = "station_ball"
"""A sweep's tool: the ball (``_sweep_tool``)."""
STRING_MAX = 80
"""The most characters a RAPID string holds."""


def paths(out: Path) -> tuple[Path]:
    return (out,)


def write(p: Program) -> tuple[str]:
    """The RAPID module of ``p``."""
    notes = header(p, "[[x, y, z], [q1, q2, q3, q4]]: mm and the quaternion w, x, y, z", "wobj0")
    mo = p.motion
    lines = [
        "MODULE StationMeasurement",
        *(f"  ! {comment_text(n)}" for n in notes),
        f"  CONST string station_robot := {rapid_string(p.robot.name)};",
        f"  CONST speeddata station_joint := [{mo.joint_mm_s:g}, {mo.joint_deg_s:g}, 5000, 1000];",
        f"  CONST speeddata station_approach := [{mo.approach_mm_s:g}, 500, 5000, 1000];",
        f"  CONST speeddata station_retreat := [{mo.retreat_mm_s:g}, 500, 5000, 1000];",
        *(_sweep_tool(p) if p.m.plan.is_sweep else []),
        *(_sweep_points(p) if p.m.plan.is_sweep else _points(p)),
        "",
        "  PROC station_measurement()",
        "    TPWrite station_robot;",
        *(_sweep_calls(p) if p.m.plan.is_sweep else _calls(p)),
        "  ENDPROC",
        "",
        *([] if p.m.plan.is_sweep else _target_proc(p)),
        "ENDMODULE",
        "",
    ]
    return ("\n".join(lines),)


def _target_proc(p: Program) -> list[str]:
    """The procedure a static plan's targets call."""
    return [
        "  PROC station_target(jointtarget standoff, jointtarget contact)",
        "    ! a joint move to the stand-off, linear onto the contact, the dwell, linear back",
        "    MoveAbsJ standoff, station_joint, fine, tool0;",
        "    MoveL CalcRobT(contact, tool0), station_approach, fine, tool0;",
        f"    WaitTime \\InPos, {p.motion.dwell_s:g};",
        "    MoveL CalcRobT(standoff, tool0), station_retreat, fine, tool0;",
        "  ENDPROC",
    ]


def _points(p: Program) -> list[str]:
    contact, standoff, lines = p.contact_deg(), p.standoff_deg(), []
    for k, target, _, skipped in p.targets():
        if not skipped:
            lines += [
                f"  CONST jointtarget t{target}_off := {_joints(standoff[k])};",
                f"  CONST jointtarget t{target}_on := {_joints(contact[k])};",
            ]
    return lines


def _sweep_tool(p: Program) -> list[str]:
    """A sweep plan's speed along the edge and its tool, the ball (``tooldata``: held by the robot,
    its TCP [mm] and orientation, then a nominal 1 kg load at the flange)."""
    mo = p.motion
    return [
        f"  CONST speeddata station_sweep := [{mo.sweep_mm_s:g}, {mo.sweep_deg_s:g}, 5000, 1000];",
        f"  PERS tooldata {BALL} := [TRUE, [[{numbers(p.robot.tool_mm, 3)}], [1, 0, 0, 0]], "
        "[1, [0, 0, 1], [1, 0, 0, 0], 0, 0, 0]];",
    ]


def _sweep_points(p: Program) -> list[str]:
    """A sweep plan's jointtargets: every waypoint's contact, each pass's two stand-offs."""
    contact, standoff, lines = p.contact_deg(), p.standoff_deg(), []
    for _, _, rows, skipped in p.passes():
        if skipped:
            continue
        for k in (rows[0], rows[-1]):
            lines.append(f"  CONST jointtarget t{p.m.plan.target[k]}_off := {_joints(standoff[k])};")
        lines += [f"  CONST jointtarget t{p.m.plan.target[k]}_on := {_joints(contact[k])};" for k in rows]
    return lines


def _sweep_calls(p: Program) -> list[str]:
    """A sweep plan's moves, pass by pass (module notes)."""
    mo, target = p.motion, p.m.plan.target
    zone = f"z{mo.blend_mm:g}"

    def moves(number, line, rows) -> list[str]:
        first, last = target[rows[0]], target[rows[-1]]
        return [
            f"    ! pass {number}, line {line}: {len(rows)} waypoints, targets {first}..{last}",
            f"    MoveAbsJ t{first}_off, station_joint, fine, {BALL};",
            f"    MoveL CalcRobT(t{first}_on, {BALL}), station_approach, fine, {BALL};",
            f"    WaitTime \\InPos, {mo.dwell_s:g};",
            *(
                f"    MoveL CalcRobT(t{t}_on, {BALL}), station_sweep, {zone}, {BALL};"
                for t in target[rows[1:-1]]
            ),
            f"    MoveL CalcRobT(t{last}_on, {BALL}), station_sweep, fine, {BALL};",
            f"    WaitTime \\InPos, {mo.dwell_s:g};",
            f"    MoveL CalcRobT(t{last}_off, {BALL}), station_retreat, fine, {BALL};",
        ]

    return each_pass(p, "    ! pass {number} left out: no stand-off within the joint limits at an end", moves)


def _calls(p: Program) -> list[str]:
    quat, lines = quaternion_wxyz(p.m.pose[:, 3:]), []
    for k, target, line, skipped in p.targets():
        if skipped:
            lines.append(f"    ! target {target} left out: no stand-off within the joint limits")
            continue
        lines += [
            f"    ! target {target}, line {line}: contact [[{numbers(p.m.pose[k, :3], 3)}], "
            f"[{numbers(quat[k], 6)}]], stand-off {p.m.distance_mm[k]:g} mm",
            f"    station_target t{target}_off, t{target}_on;",
        ]
    return lines


def _joints(q_deg) -> str:
    return f"[[{numbers(q_deg, 4)}], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]]"


def rapid_string(text: str) -> str:
    """``text`` as a RAPID string literal whose value is ``program_text(text)`` (printable ASCII),
    cut to ``STRING_MAX`` characters: a quote doubled, a backslash written ``\\\\``."""
    value = program_text(text)[:STRING_MAX]
    return '"' + value.replace("\\", "\\\\").replace('"', '""') + '"'
