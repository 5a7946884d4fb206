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
    """The rows (``COLUMNS``) of every target the program measures."""
    m = p.m
    quat, abc, wpr = quaternion_wxyz(m.pose[:, 3:]), kuka_abc(m.pose[:, 3:]), fanuc_wpr(m.pose[:, 3:])
    contact, standoff = p.contact_deg(), p.standoff_deg()
    out = [",".join(COLUMNS)]
    for k, target, line, skipped in p.targets():
        if skipped:
            continue
        cells = [
            f"{target},{line}",
            numbers(m.pose[k], 4, ","),
            numbers(quat[k], 8, ","),
            numbers(m.approach[k], 6, ","),
            numbers(m.standoff_mm[k], 4, ","),
            numbers(contact[k], 6, ","),
            numbers(standoff[k], 6, ","),
            f"{p.motion.dwell_s:g}",
            numbers(abc[k], 4, ","),
            numbers(wpr[k], 4, ","),
        ]
        out.append(",".join(cells))
    return ("\n".join(out) + "\n",)
