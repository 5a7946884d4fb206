"""``poses-csv``: one row per measured target (``COLUMNS``), for a controller without a writer here.

Columns, in order: ``target``, ``line`` (the plan's target and gauge-line ids); the contact pose of
the nominal model's TCP in its base frame: ``x_mm, y_mm, z_mm`` and the rotation vector ``rx_deg,
ry_deg, rz_deg``; the same orientation as a quaternion ``qw, qx, qy, qz`` (w first, w >= 0: ABB's
q1..q4); the unit approach ``ax, ay, az``; the stand-off position ``standoff_x_mm..standoff_z_mm``;
the contact joints ``q1_deg..q6_deg`` and the stand-off's ``standoff_q1_deg..standoff_q6_deg``, both
in the controller's convention (the robot file's ``[controller]``); ``dwell_s``; the orientation
again as KUKA's ``kuka_a_deg, kuka_b_deg, kuka_c_deg`` (Z-Y'-X'') and Fanuc's ``fanuc_w_deg,
fanuc_p_deg, fanuc_r_deg`` (turns about the fixed x, y, z). A target left out (no stand-off within
the joint limits) has no row.

A sweep plan: one row per waypoint in sweep order and a last column ``pass`` (the pass's id); a pass
is the controller's to sweep as one blended linear move through its rows, from the first row's
stand-off to the last row's (``dwell_s`` at those two, 0 between: the tool does not stop). A pass
with no stand-off at an end has no rows.
"""

from __future__ import annotations

from pathlib import Path

from station.formats.plan import APPROACH_COLUMNS, POSE_COLUMNS
from station.formats.samples import Q_COLUMNS
from station.jobs.programs.common import Program, fanuc_wpr, kuka_abc, numbers, quaternion_wxyz

COLUMNS = (
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
    "kuka_a_deg",
    "kuka_b_deg",
    "kuka_c_deg",
    "fanuc_w_deg",
    "fanuc_p_deg",
    "fanuc_r_deg",
)


def paths(out: Path) -> tuple[Path]:
    return (out,)


def write(p: Program) -> tuple[str]:
    """The rows (``COLUMNS``, and ``pass`` for a sweep plan) of every target the program measures."""
    m = p.m
    quat, abc, wpr = quaternion_wxyz(m.pose[:, 3:]), kuka_abc(m.pose[:, 3:]), fanuc_wpr(m.pose[:, 3:])
    contact, standoff = p.contact_deg(), p.standoff_deg()

    def row(k: int, dwell_s: float, extra: str = "") -> str:
        cells = [
            f"{m.plan.target[k]},{m.plan.line[k]}",
            numbers(m.pose[k], 4, ","),
            numbers(quat[k], 8, ","),
            numbers(m.approach[k], 6, ","),
            numbers(m.standoff_mm[k], 4, ","),
            numbers(contact[k], 6, ","),
            numbers(standoff[k], 6, ","),
            f"{dwell_s:g}",
            numbers(abc[k], 4, ","),
            numbers(wpr[k], 4, ","),
        ]
        return ",".join(cells) + extra

    dwell = p.motion.dwell_s
    if not m.plan.is_sweep:
        return _text(COLUMNS, [row(k, dwell) for k, _, _, skipped in p.targets() if not skipped])
    rows = [
        row(k, dwell if k in (rows[0], rows[-1]) else 0.0, f",{number}")
        for number, _, rows, skipped in p.passes()
        if not skipped
        for k in rows
    ]
    return _text((*COLUMNS, "pass"), rows)


def _text(columns, rows: list[str]) -> tuple[str]:
    return ("\n".join([",".join(columns), *rows]) + "\n",)
