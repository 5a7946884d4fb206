"""``station export``: a robot model (a corrected table) where robots use it, and what the user must
know about it (notes, printed and, where the format has comments, written in the file)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from calib.frames import joint_origins, rpy_from_matrix
from station.formats.exports import Chain, Origin, dh_csv_text, ur_kinematics_yaml, urdf_text
from station.formats.tables import RobotFile

FORMATS = ("urdf", "ur-yaml", "dh-csv")
NO_HASH = "unknown"
DH_CSV_ORDER = [3, 2, 1, 0]  # RobotFile.table_deg's theta, d, a, alpha -> alpha, a, d, theta


@dataclass(frozen=True)
class Export:
    """The file's ``text``, the ``notes`` to print and the ``warnings`` (a file that may not be
    what the user wants)."""

    text: str
    notes: list[str]
    warnings: list[str] = field(default_factory=list)


def export(
    robot: RobotFile, fmt: str, *, source: str, nominal: RobotFile | None = None, hash_: str | None = None
) -> Export:
    """``robot`` (read from ``source``) in format ``fmt``; ``nominal`` gives the dh-csv deltas and
    a controller hash the robot file lacks; ``hash_`` overrides both. No format holds the joint-space
    terms (compliance, harmonics): a note says which the file leaves out."""
    done = _geometry(robot, fmt, source, nominal, hash_)
    terms = [t.name for t in robot.terms()]
    if not terms:
        return done
    note = TERMS_LEFT_OUT.format(fmt=fmt, terms=", ".join(terms))
    return Export(done.text, [*done.notes, note], done.warnings)


MAP_LEFT_OUT = (
    "{table}'s residual map ({file}) is left out: {fmt} holds a table, not the error learnt near "
    "the measured poses; `station compensate --table {table}` applies it"
)
"""The one line on stderr where the exported table carries a residual map (``[map]``)."""


def map_left_out(robot: RobotFile, fmt: str, source: str) -> str | None:
    """What an export of ``robot`` (read from ``source``) leaves out of its residual map, None where
    it carries none."""
    if robot.map is None:
        return None
    return MAP_LEFT_OUT.format(table=source, file=robot.map.file, fmt=fmt)


UNIVERSAL_ROBOT = re.compile(r"^\s*(ur\s?-?\d|universal robots)", re.IGNORECASE)
"""A robot name Universal Robots' kinematics file is meant for: UR3, UR10e, UR-16, Universal Robots ..."""

NOT_A_UR = (
    "{name} is not a Universal Robots arm by its name: ur-yaml is the kinematics file of UR's "
    "controllers and ROS driver, which expect a UR's joint layout; for this robot use --format urdf "
    "or dh-csv (name it UR... in the robot file if it is a UR)"
)


TERMS_LEFT_OUT = (
    "{fmt} holds the geometry only: the table's joint-space terms ({terms}) are left out, so a "
    "controller running this model misses what they correct; `station compensate` applies them"
)


def _geometry(
    robot: RobotFile, fmt: str, source: str, nominal: RobotFile | None, hash_: str | None
) -> Export:
    if fmt == "urdf":
        return _urdf(robot, source)
    if fmt == "ur-yaml":
        known = robot.controller_hash or (nominal.controller_hash if nominal else None)
        done = _ur_yaml(robot, source, hash_ or known)
        if UNIVERSAL_ROBOT.match(robot.name):
            return done
        return Export(done.text, done.notes, [NOT_A_UR.format(name=robot.name)])
    return _dh_csv(robot, nominal)


def _dh_csv(robot: RobotFile, nominal: RobotFile | None) -> Export:
    """The table in the robot file's own convention (a modified one's rows as written, its flange
    in a note), the deltas against ``nominal``; a nominal in another convention: both standard."""
    own = nominal is None or nominal.convention == robot.convention
    table = (robot.file_table_deg() if own else robot.table_deg())[:, DH_CSV_ORDER]
    deltas = None
    notes = []
    if nominal is not None:
        deltas = table - (nominal.file_table_deg() if own else nominal.table_deg())[:, DH_CSV_ORDER]
        notes.append("delta_* columns: this table minus the nominal one")
    if not own:
        notes.append("the nominal robot is in another convention: both written as standard D-H")
    elif robot.convention == "mdh":
        flange = robot.flange.model_dump() if robot.flange else {"a_mm": 0.0, "alpha_deg": 0.0}
        notes.append(
            "Craig's modified D-H (convention mdh): row i holds alpha and a of the link before joint "
            f"i; the flange after joint 6: a_mm {flange['a_mm']:.4f}, alpha_deg {flange['alpha_deg']:.5f}"
        )
    return Export(dh_csv_text(table, deltas), notes)


def provenance(robot: RobotFile, source: str) -> str:
    """One line: where the model comes from."""
    cal = robot.calibration or {}
    how = f", calibrated {cal['date_utc']} ({cal.get('method', '?')})" if "date_utc" in cal else ""
    return f"{robot.name} from {source}{how}; written by station export"


def _origins(robot: RobotFile) -> list[Origin]:
    """The joint origins ``O_1 .. O_7`` of ``calib.frames`` in metres and URDF rpy."""
    return [
        Origin(tuple(o[:3, 3] / 1000.0), tuple(rpy_from_matrix(o[:3, :3])))
        for o in joint_origins(robot.model().dh)
    ]


def _urdf(robot: RobotFile, source: str) -> Export:
    origins = _origins(robot)
    tool = np.asarray(robot.tool_mm)
    chain = Chain(
        robot.name,
        tuple(origins[:6]),
        robot.model().limits,
        origins[6],
        Origin(tuple(tool / 1000.0), (0.0, 0.0, 0.0)),
    )
    comments = [
        provenance(robot, source),
        "joint_i takes the controller's reading of joint i [rad]: the table's offsets are in the origins",
        "base_link is the robot's base frame (D-H frame 0); flange is the D-H flange frame; "
        f"tcp is tool_mm = {list(robot.tool_mm)} mm in it",
        "geometry only (no inertia, meshes, effort or velocity limits: set those from the datasheet)",
    ]
    return Export(urdf_text(chain, comments), [])


def _ur_yaml(robot: RobotFile, source: str, hash_: str | None) -> Export:
    origins = _origins(robot)
    dh = robot.model().dh
    notes = [
        "the controller keeps its factory model "
        f"(hash {hash_ or NO_HASH}): its own Cartesian moves and poses (movel, pose targets, the "
        "pendant's TCP readout) are not corrected; run joint targets computed with this file, or pass "
        "Cartesian programs through `station compensate`"
    ]
    if hash_ is None:
        notes.append(
            f"no controller hash (--hash, or controller_hash in the robot TOML): wrote hash {NO_HASH!r}; "
            "the UR driver will report a calibration mismatch; take it from the kinematics file "
            "ur_calibration extracts from the controller"
        )
    if abs(dh[5, 2]) > 1e-6 or abs(dh[5, 3]) > 1e-9:
        notes.append(
            f"the table puts the flange {dh[5, 2]:.4f} mm along x of wrist_3_link, turned "
            f"{np.degrees(dh[5, 3]):.5f} deg about it (J6 a, alpha): UR's description fixes tool0 on "
            "wrist_3_link, so add this offset to the TCP you define for the tool"
        )
    if np.any(np.asarray(robot.tool_mm) != 0.0):
        notes.append(
            f"tool_mm = {list(robot.tool_mm)} mm is a TCP: define it on the controller or end effector"
        )
    text = ur_kinematics_yaml(tuple(origins[:6]), hash_ or NO_HASH, [provenance(robot, source), *notes])
    return Export(text, notes)
