"""Fanuc TP in its ASCII ``.ls`` form: ``/PROG``, ``/ATTR``, ``/MN``, ``/POS``, ``/END``.

Per target two positions in joint representation, ``P[2i-1:"T<target> off"]`` (the stand-off) and
``P[2i:"T<target> on"]`` (the contact): ``GP1: UF : 0, UT : 1, J1= .. deg, .., J6= .. deg`` (the
controller's convention). ``/MN`` does, per target, after a comment ``! tgt <target> line <line>``:
``J P[2i-1] x% FINE`` (the joint speed as a share of the axes' top speed), ``L P[2i] v mm/sec
FINE`` (the approach speed, whole mm/s), ``WAIT s(sec)`` (the dwell), ``L P[2i-1]`` back. A
linear move to a joint position is the controller's own kinematics' straight line; the tool does
not turn on it, so the ball moves on the same straight line as the flange whatever tool 1 is. The
contact pose stands in two comments, ``X Y Z`` [mm] and ``W P R`` [deg] (turns about the fixed x,
y, z axes), in the nominal model's base frame (not necessarily the controller's world or user
frame). A TP comment holds 32 characters: the header is wrapped, ``;`` (which ends a line of
``/MN``) escaped. The program's name is the file's, in upper case: a letter, then letters,
digits or ``_``, 36 at most (R-30iB; older controllers take 8). No real controller has checked it.

A sweep plan (a ``pass`` column) numbers, per pass, its first waypoint's stand-off, its waypoints
and its last's stand-off (``"T<target> off"``, ``"T<target> on"``); ``/MN`` does ``J`` to the
stand-off, ``L`` onto the first waypoint at the approach speed ``FINE``, the dwell, ``L`` through
the waypoints at the sweep speed [mm/sec] with ``CNT100`` (continuous: the controller blends
through the point) at each but the last, ``FINE`` there, the dwell, ``L`` back to its stand-off.
The tool turns along a pass, so tool 1 must be the ball (the robot file's ``tool_mm``, said in a
comment): the controller then moves the ball, not the flange, on the edge.
"""

from __future__ import annotations

from pathlib import Path

from station.jobs.programs.common import (
    Program,
    check_name,
    comment_text,
    fanuc_wpr,
    header,
    wrapped,
)

NAME = r"[A-Z][A-Z0-9_]{0,35}"
"""A TP program's name."""
COMMENT_MAX = 32
"""The most characters a TP comment line (``!``) holds."""


def paths(out: Path) -> tuple[Path]:
    check_name(
        out.stem.upper(),
        NAME,
        "must be a TP program name (a letter, then letters, digits, _; 36 at most)",
        out,
        "program name",
    )
    return (out,)


def write(p: Program) -> tuple[str]:
    """The ``.ls`` program of ``p``."""
    notes = header(p, "X Y Z mm, W P R deg: turns about the fixed x, y, z", "world frame")
    body = [f"! {n} ;" for n in wrapped([comment_text(n, ";") for n in notes], COMMENT_MAX)]
    sweep = p.m.plan.is_sweep
    ball = "! UTOOL 1: X {:g} Y {:g} Z {:g} ;".format(*p.robot.tool_mm)
    body += ["UFRAME_NUM=0 ;", "UTOOL_NUM=1 ;", *([ball] if sweep else [])]
    body += _sweep_moves(p) if sweep else _moves(p)
    lines = [
        f"/PROG  {p.out.stem.upper()}",
        "/ATTR",
        "OWNER\t\t= MNEDITOR;",
        'COMMENT\t\t= "STATION MEASURE";',
        "PROG_SIZE\t= 0;",
        "FILE_NAME\t= ;",
        "VERSION\t\t= 0;",
        f"LINE_COUNT\t= {len(body)};",
        "MEMORY_SIZE\t= 0;",
        "PROTECT\t\t= READ_WRITE;",
        "TCD:  STACK_SIZE\t= 0,",
        "      TASK_PRIORITY\t= 50,",
        "      TIME_SLICE\t= 0,",
        "      BUSY_LAMP_OFF\t= 0,",
        "      ABORT_REQUEST\t= 0,",
        "      PAUSE_REQUEST\t= 0;",
        "DEFAULT_GROUP\t= 1,*,*,*,*;",
        "CONTROL_CODE\t= 00000000 00000000;",
        "/MN",
        *(f"{n:4d}:  {line}" for n, line in enumerate(body, start=1)),
        "/POS",
        *(_sweep_positions(p) if sweep else _positions(p)),
        "/END",
        "",
    ]
    return ("\n".join(lines),)


def _moves(p: Program) -> list[str]:
    mo, wpr, lines = p.motion, fanuc_wpr(p.m.pose[:, 3:]), []
    for n, k, target, line, skipped in _numbered(p):
        if skipped:
            lines.append(f"! tgt {target} left out ;")
            continue
        x, y, z = p.m.pose[k, :3]
        lines += [
            f"! tgt {target} line {line} ;",
            f"! X {x:.1f} Y {y:.1f} Z {z:.1f} ;",
            "! W {:.2f} P {:.2f} R {:.2f} ;".format(*wpr[k]),
            f"J P[{n}] {mo.joint_percent:.0f}% FINE ;",
            f"L P[{n + 1}] {_mm_s(mo.approach_mm_s)}mm/sec FINE ;",
            f"WAIT {mo.dwell_s:.2f}(sec) ;",
            f"L P[{n}] {_mm_s(mo.retreat_mm_s)}mm/sec FINE ;",
        ]
    return lines


def _sweep_numbered(p: Program):
    """``p.passes()``, each led by its first stand-off's position number (the waypoints follow, then
    the last stand-off; the numbers run over the passes measured)."""
    n = 1
    for number, line, rows, skipped in p.passes():
        yield n, number, line, rows, skipped
        n += 0 if skipped else len(rows) + 2


def _sweep_moves(p: Program) -> list[str]:
    mo, target, lines = p.motion, p.m.plan.target, []
    for n, number, line, rows, skipped in _sweep_numbered(p):
        if skipped:
            lines.append(f"! pass {number} left out ;")
            continue
        last = n + len(rows) + 1
        lines += [
            f"! pass {number} line {line} ;",
            f"! tgt {target[rows[0]]}..{target[rows[-1]]} ;",
            f"J P[{n}] {mo.joint_percent:.0f}% FINE ;",
            f"L P[{n + 1}] {_mm_s(mo.approach_mm_s)}mm/sec FINE ;",
            f"WAIT {mo.dwell_s:.2f}(sec) ;",
            *(f"L P[{n + 1 + j}] {_mm_s(mo.sweep_mm_s)}mm/sec CNT100 ;" for j in range(1, len(rows) - 1)),
            f"L P[{last - 1}] {_mm_s(mo.sweep_mm_s)}mm/sec FINE ;",
            f"WAIT {mo.dwell_s:.2f}(sec) ;",
            f"L P[{last}] {_mm_s(mo.retreat_mm_s)}mm/sec FINE ;",
        ]
    return lines


def _sweep_positions(p: Program) -> list[str]:
    contact, standoff, target, lines = p.contact_deg(), p.standoff_deg(), p.m.plan.target, []
    for n, _, _, rows, skipped in _sweep_numbered(p):
        if skipped:
            continue
        lines += _position(n, f"T{target[rows[0]]} off", standoff[rows[0]])
        for j, k in enumerate(rows, start=1):
            lines += _position(n + j, f"T{target[k]} on", contact[k])
        lines += _position(n + len(rows) + 1, f"T{target[rows[-1]]} off", standoff[rows[-1]])
    return lines


def _numbered(p: Program):
    """``p.targets()``, each row led by its stand-off's position number (the contact's is one more;
    the numbers run over the measured targets)."""
    n = -1
    for k, target, line, skipped in p.targets():
        n += 0 if skipped else 2
        yield n, k, target, line, skipped


def _positions(p: Program) -> list[str]:
    contact, standoff, lines = p.contact_deg(), p.standoff_deg(), []
    for n, k, target, _, skipped in _numbered(p):
        if not skipped:
            lines += _position(n, f"T{target} off", standoff[k])
            lines += _position(n + 1, f"T{target} on", contact[k])
    return lines


def _position(n: int, name: str, q_deg) -> list[str]:
    """A ``/POS`` entry: position ``n`` named ``name`` at joints ``q_deg`` [deg]."""
    joints = [f"J{j}= {v:9.3f} deg" for j, v in enumerate(q_deg, start=1)]
    return [
        f'P[{n}:"{name}"]{{',
        "   GP1:",
        "\tUF : 0, UT : 1,",
        "\t" + ",\t".join(joints[:3]) + ",",
        "\t" + ",\t".join(joints[3:]),
        "};",
    ]


def _mm_s(v: float) -> int:
    """A TP linear speed: whole mm/s, at least 1."""
    return max(1, round(v))
