"""The contract's robot model and setup files (TOML), validated at load.

Every problem becomes an ``InputError`` whose one line names the file, the key, and what is wrong.
Values stay in the contract's units (mm, degrees).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.params import DH_KEYS
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

    def table_deg(self) -> np.ndarray:
        """(6, 4) table in display units, columns as ``calib.params.DH_KEYS`` (theta_deg, d_mm, a_mm,
        alpha_deg)."""
        return np.array([[getattr(j, key) for key in DH_KEYS] for j in self.joints])

    def limits_deg(self) -> np.ndarray:
        return np.array([[j.q_min_deg, j.q_max_deg] for j in self.joints])


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


def load_robot(path) -> RobotFile:
    return validate(RobotFile, read_toml(path), str(path))


def load_setup(path) -> SetupFile:
    return validate(SetupFile, read_toml(path), str(path))


