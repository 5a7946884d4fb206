"""The robot model in other tools' formats (``station export``): URDF, Universal Robots' ROS
``kinematics:`` YAML, and a D-H CSV. Each writer takes values already in its format's units
(URDF and UR: metres and radians; CSV: the contract's mm and degrees) and writes text."""

from __future__ import annotations

import csv
import io
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import yaml

UR_ENTRIES = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
"""The joints of Universal Robots' description, base to wrist, as its ``kinematics:`` names them."""

DH_CSV_COLUMNS = ("joint", "alpha_deg", "a_mm", "d_mm", "theta_deg")


@dataclass(frozen=True)
class Origin:
    """A fixed transform as URDF writes it: ``xyz`` [m] and roll-pitch-yaw ``rpy`` [rad]."""

    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]


@dataclass(frozen=True)
class Chain:
    """A serial chain: six revolute joints at ``joints`` origins with ``limits`` (6, 2) [rad],
    then the ``flange`` fixed on the last link and the ``tcp`` fixed on the flange."""

    name: str
    joints: tuple[Origin, ...]
    limits: np.ndarray
    flange: Origin
    tcp: Origin


def urdf_text(chain: Chain, comments: list[str]) -> str:
    """URDF of ``chain``: links ``base_link``, ``link_1`` .. ``link_6``, ``flange``, ``tcp``; joints
    ``joint_1`` .. ``joint_6`` (revolute about z), ``flange_joint`` and ``tcp_joint`` (fixed)."""
    robot = ET.Element("robot", name=chain.name)
    for text in comments:
        robot.append(ET.Comment(f" {text} "))
    links = ["base_link", *(f"link_{i}" for i in range(1, 7)), "flange", "tcp"]
    ET.SubElement(robot, "link", name=links[0])
    for i, origin in enumerate(chain.joints):
        joint = _joint(robot, f"joint_{i + 1}", "revolute", links[i], links[i + 1], origin)
        ET.SubElement(joint, "axis", xyz="0 0 1")
        lower, upper = chain.limits[i]
        # the station knows no effort or velocity limits; URDF requires the attributes
        ET.SubElement(joint, "limit", lower=_num(lower), upper=_num(upper), effort="0", velocity="0")
    _joint(robot, "flange_joint", "fixed", links[6], links[7], chain.flange)
    _joint(robot, "tcp_joint", "fixed", links[7], links[8], chain.tcp)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _joint(robot: ET.Element, name: str, kind: str, parent: str, child: str, origin: Origin) -> ET.Element:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    ET.SubElement(joint, "origin", xyz=" ".join(map(_num, origin.xyz)), rpy=" ".join(map(_num, origin.rpy)))
    ET.SubElement(robot, "link", name=child)
    return joint


def ur_kinematics_yaml(joints: tuple[Origin, ...], hash_: str, comments: list[str]) -> str:
    """Universal Robots' ``kinematics:`` file: one ``x y z roll pitch yaw`` entry per joint origin
    (``UR_ENTRIES``), and the controller's calibration ``hash``."""
    kinematics = {}
    for name, origin in zip(UR_ENTRIES, joints, strict=True):
        x, y, z = (_clean(v) for v in origin.xyz)
        roll, pitch, yaw = (_clean(v) for v in origin.rpy)
        kinematics[name] = {"x": x, "y": y, "z": z, "roll": roll, "pitch": pitch, "yaw": yaw}
    kinematics["hash"] = hash_
    header = "".join(f"# {text}\n" for text in comments)
    return header + yaml.safe_dump({"kinematics": kinematics}, sort_keys=False)


def dh_csv_text(table: np.ndarray, deltas: np.ndarray | None) -> str:
    """``joint,alpha_deg,a_mm,d_mm,theta_deg`` per joint from ``table`` (6, 4) in that column order,
    and with ``deltas`` (6, 4, same order) the ``delta_...`` columns beside them."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    names = list(DH_CSV_COLUMNS)
    if deltas is not None:
        names += [f"delta_{c}" for c in DH_CSV_COLUMNS[1:]]
    writer.writerow(names)
    for j in range(6):
        values = list(table[j]) + ([] if deltas is None else list(deltas[j]))
        writer.writerow([j + 1, *(f"{round(float(v), 6) + 0.0:.6f}" for v in values)])
    return out.getvalue()


def _clean(v: float) -> float:
    """``v`` rounded to 1e-12 (no float noise, no negative zero)."""
    return round(float(v), 12) + 0.0


def _num(v: float) -> str:
    return f"{_clean(v):.12g}"
