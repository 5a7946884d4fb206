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
"""

from __future__ import annotations

from pathlib import Path

from errors import InputError
from station.jobs.programs.common import Program, check_name, comment_text, header, kuka_abc

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
    return "\n".join([*top, f"DEF {name}( )", *comments, *_setup(p), *_moves(p), "END", ""]), "\n".join(
        [*top, f"DEFDAT {name}", *comments, *_points(p), "ENDDAT", ""]
    )


def _setup(p: Program) -> list[str]:
    """The frames, joint speeds and accelerations before the first move."""
    percent = f"{p.motion.joint_percent:g}"
    return [
        "DECL INT I",
        "$TOOL = $NULLFRAME  ; the flange: the linear moves do not turn the tool",
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
