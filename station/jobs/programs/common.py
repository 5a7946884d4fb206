"""What every program writer shares: the program's inputs, the joints in the controller's
convention, the contact pose in each vendor's convention, the header's words and the escaping of
text for each language's comments and strings."""

from __future__ import annotations

import re
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from errors import InputError
from station.formats.tables import RobotFile
from station.jobs.measurement import Measurement, Motion, program_text


@dataclass(frozen=True)
class Program:
    """A program to write: the measurement ``m`` on ``robot`` (whose ``[controller]`` numbers the
    joints), the plan's name ``source``, the ``motion`` and the ``--out`` path ``out``."""

    m: Measurement
    robot: RobotFile
    source: str
    motion: Motion
    out: Path

    def contact_deg(self) -> np.ndarray:
        """The contact joints (M, 6) in the controller's convention [deg]."""
        return self.robot.controller.controller_deg(self.m.plan.q_deg)

    def standoff_deg(self) -> np.ndarray:
        """The stand-off joints (M, 6) in the controller's convention [deg]."""
        return self.robot.controller.controller_deg(self.m.standoff_q_deg)

    def targets(self) -> Iterator[tuple[int, int, int, bool]]:
        """Per plan target, in plan order: its row, id, gauge line and whether it is left out."""
        for k in range(len(self.m.plan)):
            yield k, int(self.m.plan.target[k]), int(self.m.plan.line[k]), bool(self.m.skipped[k])

    def passes(self) -> Iterator[tuple[int, int, np.ndarray, bool]]:
        """Per pass of a sweep plan, in order: its id, gauge line, plan rows (the waypoints in sweep
        order) and whether it is left out (no stand-off at its first or last waypoint)."""
        plan = self.m.plan
        for rows in plan.passes():
            ends = self.m.skipped[[rows[0], rows[-1]]]
            yield int(plan.sweep_pass[rows[0]]), int(plan.line[rows[0]]), rows, bool(ends.any())


def each_pass(p: Program, left_out: str, moves) -> list[str]:
    """The lines of every pass of a sweep plan, in order: ``moves(number, line, rows)`` (its id,
    gauge line and plan rows), or for a pass left out ``left_out`` with ``{number}`` its id."""
    lines: list[str] = []
    for number, line, rows, skipped in p.passes():
        lines += [left_out.format(number=number)] if skipped else moves(number, line, rows)
    return lines


def header(p: Program, pose_words: str, frame: str = "base frame", units: str = "deg") -> list[str]:
    """The header comment's lines (no comment marker, not yet escaped): what the program does, the
    joints' ``units`` and convention, the contact poses' convention ``pose_words`` and the
    controller's ``frame`` their base frame may differ from."""
    convention = "" if p.robot.controller.identity else f" (robot file [controller]: {_convention(p.robot)})"
    moves = _sweep_moves(p) if p.m.plan.is_sweep else _target_moves(p)
    return [
        *moves,
        f"Joints in {units}, in the controller's convention: reading = joint_sign * (model - "
        f"joint_offset_deg){convention}.",
        f"Contact poses (comments): the nominal model's TCP in its base frame ({pose_words}),",
        f"which may differ from the controller's {frame}: the moves use joints only.",
        "The contact poses are the nominal model's: the dial reads how far the real tool lands off them.",
        "No real controller has checked this program: run it first at low override, step by step.",
    ]


def _target_moves(p: Program) -> list[str]:
    """The header's words for a static plan's moves."""
    mo = p.motion
    return [
        f"Measurement program for {p.robot.name}: {len(p.m.plan)} targets from {p.source} (station program).",
        f"Per target: a joint move to a stand-off {mo.standoff_mm:g} mm back along the approach, a linear "
        f"move at {mo.approach_mm_s:g} mm/s onto the contact,",
        f"a {mo.dwell_s:g} s dwell (station sample captures there), a linear move back at "
        f"{mo.retreat_mm_s:g} mm/s.",
    ]


def _sweep_moves(p: Program) -> list[str]:
    """The header's words for a sweep plan's moves."""
    mo, n = p.motion, len(p.m.plan.passes())
    return [
        f"Sweep program for {p.robot.name}: {n} passes, {len(p.m.plan)} waypoints from {p.source} (station "
        "program).",
        f"Per pass: a joint move to a stand-off {mo.standoff_mm:g} mm back along the approach from its first "
        f"waypoint, a linear move at {mo.approach_mm_s:g} mm/s onto it, a {mo.dwell_s:g} s dwell,",
        f"linear moves through its waypoints at {mo.sweep_mm_s:g} mm/s (the tool turning at most "
        f"{mo.sweep_deg_s:g} deg/s), blended {mo.blend_mm:g} mm at each but the last: the waypoints lie",
        "on one gauge edge, so the blends keep the tool on it (station sample streams meanwhile);",
        f"a {mo.dwell_s:g} s dwell at the last, a linear move back to its stand-off at "
        f"{mo.retreat_mm_s:g} mm/s.",
    ]


def _convention(robot: RobotFile) -> str:
    c = robot.controller
    return f"joint_sign {list(c.joint_sign)}, joint_offset_deg {[float(v) for v in c.joint_offset_deg]}"


def kuka_abc(rotvec_deg) -> np.ndarray:
    """KUKA's A, B, C [deg] (..., 3) of rotation vectors [deg] (..., 3): R = Rz(A) Ry(B) Rx(C),
    turns about z, then the new y', then x'' (intrinsic Z-Y'-X'')."""
    r = Rotation.from_rotvec(np.reshape(rotvec_deg, (-1, 3)), degrees=True).as_matrix()
    a = np.arctan2(r[:, 1, 0], r[:, 0, 0])
    b = np.arctan2(-r[:, 2, 0], np.hypot(r[:, 0, 0], r[:, 1, 0]))
    c = np.arctan2(r[:, 2, 1], r[:, 2, 2])
    return np.degrees(np.stack([a, b, c], axis=-1)).reshape(np.shape(rotvec_deg))


def fanuc_wpr(rotvec_deg) -> np.ndarray:
    """Fanuc's W, P, R [deg] (..., 3) of rotation vectors [deg] (..., 3): turns about the fixed x
    (W), y (P) and z (R) axes in that order, R = Rz(R) Ry(P) Rx(W): KUKA's C, B, A."""
    return kuka_abc(rotvec_deg)[..., ::-1]


def quaternion_wxyz(rotvec_deg) -> np.ndarray:
    """ABB's quaternion q1..q4 = w, x, y, z (..., 4) of rotation vectors [deg] (..., 3), w >= 0."""
    q = Rotation.from_rotvec(np.reshape(rotvec_deg, (-1, 3)), degrees=True).as_quat()[:, [3, 0, 1, 2]]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(*np.shape(rotvec_deg)[:-1], 4)


def comment_text(text: str, ends: str = "") -> str:
    """``text`` for a comment that runs to the line's end (``program_text``: no line break), with
    each character of ``ends`` (those that end a statement in the language) escaped too."""
    safe = program_text(text)
    return re.sub(f"[{re.escape(ends)}]", lambda c: f"\\x{ord(c.group()):02x}", safe) if ends else safe


def wrapped(lines: list[str], width: int) -> list[str]:
    """``lines`` (escaped: no line breaks left to fold) wrapped to ``width`` characters, for
    languages whose comments are short."""
    return [part for line in lines for part in textwrap.wrap(line, width, break_on_hyphens=False)]


def numbers(v, digits: int, sep: str = ", ") -> str:
    """The numbers ``v`` with ``digits`` decimals, joined by ``sep``."""
    return sep.join(f"{x:.{digits}f}" for x in v)


def check_name(name: str, pattern: str, rule: str, out: Path, what: str) -> str:
    """``name`` (derived from ``--out`` ``out``) if it matches ``pattern``, else InputError saying
    ``rule`` for ``what``."""
    if not re.fullmatch(pattern, name):
        raise InputError(
            f"--out {program_text(str(out))}: {what} {program_text(name)!r} (from the file name) {rule}"
        )
    return name
