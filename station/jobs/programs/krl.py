"""KUKA KRL: a ``.src`` (``DEF name( ) ... END``) and its ``.dat`` (``DEFDAT name ... ENDDAT``).

The ``.dat`` declares per target two axis-specific points ``DECL E6AXIS XT<target>_OFF`` (the
stand-off) and ``XT<target>_ON`` (the contact): ``{A1 .., A6 .., E1 0, .., E6 0}``, deg in the
controller's convention (KUKA's A1, A4 and A6 turn against the usual D-H axes: the robot file's
``[controller] joint_sign``). A comment before them names the target's gauge line and its contact
pose in KUKA's convention ``X, Y, Z`` [mm], ``A, B, C`` [deg] (intrinsic Z-Y'-X'': A about z, B
about y', C about x''), in the nominal model's base frame, which need not be the controller's
``$ROBROOT``/``$BASE``: the program moves by the axis points only. The ``.src`` does, per target,
``PTP`` to the stand-off, ``LIN`` onto the contact at ``$VEL.CP`` = the approach speed [m/s],
``WAIT SEC`` the dwell (it also stops the advance run, so the robot stands at the contact first),
``LIN`` back. ``$TOOL`` and ``$BASE`` are ``$NULLFRAME``: the linear moves do not turn the tool, so
the ball moves on the same straight line as the flange. The module's name is the file's: a KRL
name (a letter or ``_``, then letters, digits or ``_``, 24 at most). No real controller has
checked these files.

A sweep plan (a ``pass`` column) declares ``XT<target>_ON`` for every waypoint and
``XT<target>_OFF`` for the first and last of each pass; per pass the ``.src`` does ``PTP`` to the
first's stand-off, ``LIN`` onto it at the approach speed, ``WAIT SEC`` the dwell, then ``LIN`` through
the waypoints at ``$VEL.CP`` = the sweep speed [m/s], approximated (``C_DIS``: blended where the
path comes within ``$APO.CDIS`` [mm] of the point) at each but the last, ``$VEL.ORI1``/``ORI2`` the
turn rate [deg/s], ``$TOOL`` the ball (the robot file's ``tool_mm``: the tool turns along a pass,
so the ball, not the flange, must move on the edge); ``WAIT SEC`` the dwell at the last (which
stops the advance run), ``LIN`` back to its stand-off.
"""

from __future__ import annotations

from pathlib import Path

from errors import InputError
from station.jobs.programs.common import Program, check_name, comment_text, each_pass, header, kuka_abc

LEFT_OUT = "; pass {number} left out: no stand-off within the joint limits at an end"
NAME = r"[A-Za-z_][A-Za-z0-9_]{0,23}"
"""A KRL name: a module's (its file's) and a point's."""


def paths(out: Path) -> tuple[Path, Path]:
    """The ``.src`` ``out`` and its ``.dat`` beside it."""
    if out.suffix.lower() != ".src":
        raise InputError(
            f"--out {comment_text(str(out))}: krl writes a .src and its .dat: name the .src file"
        )
    check_name(
        out.stem,
        NAME,
        "must be a KRL name (a letter or _, then letters, digits, _; 24 at most)",
        out,
        "module name",
    )
    return out, out.with_suffix(".dat")


def write(p: Program) -> tuple[str, str]:
    """The ``.src`` and ``.dat`` of ``p``."""
    name = p.out.stem
    notes = header(p, "X, Y, Z mm and A, B, C deg: intrinsic Z-Y'-X''", "$ROBROOT/$BASE")
    top = ["&ACCESS RVP", "&REL 1"]
    comments = [f"; {comment_text(n)}" for n in notes]
    moves, points = (_sweep_moves(p), _sweep_points(p)) if p.m.plan.is_sweep else (_moves(p), _points(p))
    return "\n".join([*top, f"DEF {name}( )", *comments, *_setup(p), *moves, "END", ""]), "\n".join(
        [*top, f"DEFDAT {name}", *comments, *points, "ENDDAT", ""]
    )


def _setup(p: Program) -> list[str]:
    """The frames, joint speeds and accelerations before the first move."""
    percent = f"{p.motion.joint_percent:g}"
    x, y, z = p.robot.tool_mm
    tool = (
        f"$TOOL = {{X {x:g}, Y {y:g}, Z {z:g}, A 0, B 0, C 0}}  ; the ball: a pass turns the tool about it"
        if p.m.plan.is_sweep
        else "$TOOL = $NULLFRAME  ; the flange: the linear moves do not turn the tool"
    )
    return [
        "DECL INT I",
        tool,
        "$BASE = $NULLFRAME",
        "FOR I = 1 TO 6",
        f"  $VEL_AXIS[I] = {percent}  ; % of each axis' top speed",
        f"  $ACC_AXIS[I] = {percent}",
        "ENDFOR",
        "$ACC.CP = 0.5  ; m/s^2",
        "$VEL.ORI1 = 50",
        "$VEL.ORI2 = 50",
        "$ACC.ORI1 = 100",
        "$ACC.ORI2 = 100",
    ]


def _moves(p: Program) -> list[str]:
    mo, lines = p.motion, []
    for k, target, line, skipped in p.targets():
        if skipped:
            lines.append(f"; target {target} left out: no stand-off within the joint limits")
            continue
        lines += [
            f"; target {target}, line {line}: stand-off {p.m.distance_mm[k]:g} mm",
            f"PTP XT{target}_OFF",
            f"$VEL.CP = {mo.approach_mm_s / 1000.0:.4f}  ; m/s onto the contact",
            f"LIN XT{target}_ON",
            f"WAIT SEC {mo.dwell_s:g}",
            f"$VEL.CP = {mo.retreat_mm_s / 1000.0:.4f}",
            f"LIN XT{target}_OFF",
        ]
    return lines


def _sweep_moves(p: Program) -> list[str]:
    """The ``.src`` moves of a sweep plan (module notes)."""
    mo, target = p.motion, p.m.plan.target

    def moves(number, line, rows) -> list[str]:
        first, last = target[rows[0]], target[rows[-1]]
        return [
            f"; pass {number}, line {line}: {len(rows)} waypoints, targets {first}..{last}",
            f"PTP XT{first}_OFF",
            f"$VEL.CP = {mo.approach_mm_s / 1000.0:.4f}  ; m/s onto the contact",
            f"LIN XT{first}_ON",
            f"WAIT SEC {mo.dwell_s:g}",
            f"$VEL.CP = {mo.sweep_mm_s / 1000.0:.4f}  ; m/s along the edge",
            f"$VEL.ORI1 = {mo.sweep_deg_s:g}",
            f"$VEL.ORI2 = {mo.sweep_deg_s:g}",
            *(f"LIN XT{t}_ON C_DIS" for t in target[rows[1:-1]]),
            f"LIN XT{last}_ON",
            f"WAIT SEC {mo.dwell_s:g}",
            f"$VEL.CP = {mo.retreat_mm_s / 1000.0:.4f}",
            f"LIN XT{last}_OFF",
        ]

    blend = f"$APO.CDIS = {mo.blend_mm:g}  ; mm: the blend at a pass's waypoints"
    return [blend, *each_pass(p, LEFT_OUT, moves)]


def _sweep_points(p: Program) -> list[str]:
    """The ``.dat`` points of a sweep plan: every waypoint's contact, each pass's two stand-offs."""
    contact, standoff, abc = p.contact_deg(), p.standoff_deg(), kuka_abc(p.m.pose[:, 3:])
    lines = []
    for number, line, rows, skipped in p.passes():
        if skipped:
            continue
        for k in rows:
            target = p.m.plan.target[k]
            pose = ", ".join(
                f"{n} {v:.4f}" for n, v in zip("XYZABC", [*p.m.pose[k, :3], *abc[k]], strict=True)
            )
            lines.append(f"; target {target}, line {line}, pass {number}: contact pose {{{pose}}}")
            if k in (rows[0], rows[-1]):
                lines.append(f"DECL E6AXIS XT{target}_OFF={_axes(standoff[k])}")
            lines.append(f"DECL E6AXIS XT{target}_ON={_axes(contact[k])}")
    return lines


def _points(p: Program) -> list[str]:
    contact, standoff, abc = p.contact_deg(), p.standoff_deg(), kuka_abc(p.m.pose[:, 3:])
    lines = []
    for k, target, line, skipped in p.targets():
        if skipped:
            continue
        pose = ", ".join(f"{n} {v:.4f}" for n, v in zip("XYZABC", [*p.m.pose[k, :3], *abc[k]], strict=True))
        lines += [
            f"; target {target}, line {line}: contact pose {{{pose}}}",
            f"DECL E6AXIS XT{target}_OFF={_axes(standoff[k])}",
            f"DECL E6AXIS XT{target}_ON={_axes(contact[k])}",
        ]
    return lines


def _axes(q_deg) -> str:
    """An E6AXIS aggregate of the joints ``q_deg`` [deg], the external axes 0."""
    robot = [f"A{i} {v:.4f}" for i, v in enumerate(q_deg, start=1)]
    return "{" + ", ".join([*robot, *(f"E{i} 0.0" for i in range(1, 7))]) + "}"
