"""The contract's robot model and setup files (TOML), validated at load.

Every problem becomes an ``InputError`` whose one line names the file, the key, and what is wrong.
Values stay in the contract's units (mm, degrees).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.joint_terms import TERM_KINDS, JointTerms, LinkMasses, Term
from calib.params import DH_KEYS, DH_NAMES, dh_from_degrees, display_factor
from calib.robot_model import RobotModel
from errors import InputError
from station.formats.base import read_toml, validate

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Joint(_Strict):
    """One D-H joint; optionally its link's mass and centre of mass (in D-H frame i) for the
    gravity torques, and the joint-space terms a calibration identified (``calib.joint_terms``)."""

    alpha_deg: float
    a_mm: float
    d_mm: float
    theta_deg: float
    q_min_deg: float = -180.0
    q_max_deg: float = 180.0
    mass_kg: float | None = Field(None, ge=0)
    com_mm: Vec3 | None = None
    compliance_urad_per_Nm: float | None = None
    sin1_deg: float | None = None
    cos1_deg: float | None = None
    sin2_deg: float | None = None
    cos2_deg: float | None = None
    sigma: dict[str, float] | None = None  # written by a calibration: per-parameter sigma


class Payload(_Strict):
    """What the flange carries: mass [kg] and centre of mass [mm] in the flange frame."""

    mass_kg: float = Field(ge=0)
    com_mm: Vec3 = [0.0, 0.0, 0.0]


class RobotFile(_Strict):
    """A robot model (contract: robot model TOML); a corrected table adds ``calibration`` and,
    where it identified compliances, the ``payload`` they were identified with."""

    name: str
    convention: Literal["dh"] = "dh"
    tool_mm: Vec3 = [0.0, 0.0, 0.0]
    joints: Annotated[list[Joint], Field(min_length=6, max_length=6)]
    payload: Payload | None = None
    calibration: dict | None = None
    controller_hash: str | None = None  # the controller's factory-calibration id (UR: ``hash``)

    def table_deg(self) -> np.ndarray:
        """(6, 4) table in display units, columns as ``calib.params.DH_KEYS`` (theta_deg, d_mm, a_mm,
        alpha_deg)."""
        return np.array([[getattr(j, key) for key in DH_KEYS] for j in self.joints])

    def limits_deg(self) -> np.ndarray:
        return np.array([[j.q_min_deg, j.q_max_deg] for j in self.joints])

    def link_masses(self, payload: Payload | None = None) -> LinkMasses | None:
        """The links' masses with ``payload`` (default: the file's own) lumped into link 6; None
        unless every joint gives ``mass_kg`` and ``com_mm``."""
        if any(j.mass_kg is None or j.com_mm is None for j in self.joints):
            return None
        links = LinkMasses(
            np.array([j.mass_kg for j in self.joints]), np.array([j.com_mm for j in self.joints])
        )
        payload = payload or self.payload
        return links if payload is None else links.with_payload(payload.mass_kg, payload.com_mm)

    def terms(self) -> list[Term]:
        """The joint-space terms the file carries (``calib.joint_terms``), joint by joint."""
        return [
            Term(j, key)
            for j, joint in enumerate(self.joints)
            for key in TERM_KINDS
            if getattr(joint, key) is not None
        ]

    def model(self) -> RobotModel:
        """The robot model the maths uses (internal units: rad, mm), with the terms it carries."""
        dh, terms = dh_from_degrees(self.table_deg()), self.terms()
        values = np.array([getattr(self.joints[t.joint], t.key) for t in terms], float)
        values /= display_factor([t.name for t in terms])
        return RobotModel(
            dh,
            np.array(self.tool_mm),
            np.radians(self.limits_deg()),
            JointTerms(terms, dh, self.link_masses()),
            values,
        )

    def covariance(self, where: str) -> np.ndarray | None:
        """The calibration's covariance of the robot's parameters, the table and then the terms in
        ``model()``'s order, in internal units (rad, mm, urad/(N m)), as a corrected table carries it
        (``[calibration] covariance`` in display units, rows named by ``covariance_parameters``);
        None if it has none."""
        data = (self.calibration or {}).get("covariance")
        if data is None:
            return None
        expected = list(DH_NAMES) + [t.name for t in self.terms()]
        names = (self.calibration or {}).get("covariance_parameters", list(DH_NAMES))
        try:
            cov = np.array(data, float)
        except (TypeError, ValueError):
            raise InputError(f"{where}: calibration.covariance: not a table of numbers") from None
        n = len(expected)
        if sorted(names) != sorted(expected) or cov.shape != (n, n) or not np.isfinite(cov).all():
            raise InputError(
                f"{where}: calibration.covariance: expected {n} x {n} finite numbers, one per name of "
                "calibration.covariance_parameters: J1.theta_deg, J1.d_mm, ... and each term the joints carry"
            )
        order = [names.index(name) for name in expected]
        factor = display_factor(expected)
        return cov[np.ix_(order, order)] / np.outer(factor, factor)


class SetupDrawstring(_Strict):
    anchor_mm: Vec3
    length_offset_mm: float
    sigma_mm: float = Field(0.02, gt=0)


class SetupDial(_Strict):
    axis: Vec3 | None = None
    sigma_mm: float = Field(0.002, gt=0)


class SetupLine(_Strict):
    """One gauge-block placement; ``point_mm``, ``direction`` (base frame), usable ``length_mm`` and
    the tool ``approach`` direction are needed only to plan measurements (``station plan``)."""

    id: int
    dial_axis: Vec3 | None = None
    point_mm: Vec3 | None = None
    direction: Vec3 | None = None
    length_mm: float = Field(400.0, gt=0)
    approach: Vec3 | None = None


class SetupFile(_Strict):
    """Station geometry as measured roughly (contract: setup TOML). ``line_sigma_mm``: how well the
    tool sits on the gauge edge (joint-reading noise at the TCP included); ``rho``: line-term weight;
    ``payload``: what the flange carried while measuring (for the gravity torques)."""

    drawstring: SetupDrawstring | None = None
    dial: SetupDial | None = None
    payload: Payload | None = None
    lines: list[SetupLine] = []
    line_sigma_mm: float = Field(0.01, gt=0)
    rho: float = Field(1.0, gt=0)


SAME_ROBOT_MM, SAME_ROBOT_DEG = 50.0, 10.0
"""Largest table difference between a calibrated robot and its nominal model: beyond it the two
files describe different robots."""


def check_same_robot(table: RobotFile, table_where: str, nominal: RobotFile, nominal_where: str) -> None:
    """Bad input unless ``table`` (a calibration of) and ``nominal`` are the same robot: every D-H
    parameter within ``SAME_ROBOT_MM`` / ``SAME_ROBOT_DEG``."""
    diff = np.abs(table.table_deg() - nominal.table_deg())
    limit = np.array([SAME_ROBOT_DEG, SAME_ROBOT_MM, SAME_ROBOT_MM, SAME_ROBOT_DEG])
    if (diff > limit).any():
        j, k = np.argwhere(diff > limit)[0]
        key = ("theta_deg", "d_mm", "a_mm", "alpha_deg")[k]
        raise InputError(
            f"{table_where}: joints.{j}.{key} differs from {nominal_where}'s by {diff[j, k]:.1f}: "
            "not a calibration of that robot"
        )


def check_same_tool(table: RobotFile, table_where: str, nominal: RobotFile, nominal_where: str) -> None:
    """Bad input unless both robot files put the TCP at the same ``tool_mm``."""
    if not np.allclose(table.tool_mm, nominal.tool_mm, atol=1e-6):
        raise InputError(
            f"{table_where}: tool_mm {table.tool_mm} differs from {nominal_where}'s {nominal.tool_mm}: "
            "the program's TCP must be the same in both"
        )


def load_robot(path) -> RobotFile:
    robot = validate(RobotFile, read_toml(path), str(path))
    compliant = [j for j, joint in enumerate(robot.joints) if joint.compliance_urad_per_Nm is not None]
    if compliant and robot.link_masses() is None:
        raise InputError(
            f"{path}: joints.{compliant[0]}.compliance_urad_per_Nm needs mass_kg and com_mm on every joint"
        )
    return robot


def load_setup(path) -> SetupFile:
    return validate(SetupFile, read_toml(path), str(path))
