"""The contract's robot model and setup files (TOML), validated at load.

Every problem becomes an ``InputError`` whose one line names the file, the key, and what is wrong.
Values stay in the contract's units (mm, degrees).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.params import DH_KEYS, DH_NAMES, dh_from_degrees, display_factor
from calib.robot_model import RobotModel
from errors import InputError
from station.formats.base import read_toml, validate

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Joint(_Strict):
    alpha_deg: float
    a_mm: float
    d_mm: float
    theta_deg: float
    q_min_deg: float = -180.0
    q_max_deg: float = 180.0
    sigma: dict[str, float] | None = None  # written by a calibration: per-parameter sigma


class RobotFile(_Strict):
    """A robot model (contract: robot model TOML); a corrected table adds ``calibration``."""

    name: str
    convention: Literal["dh"] = "dh"
    tool_mm: Vec3 = [0.0, 0.0, 0.0]
    joints: Annotated[list[Joint], Field(min_length=6, max_length=6)]
    calibration: dict | None = None
    controller_hash: str | None = None  # the controller's factory-calibration id (UR: ``hash``)

    def table_deg(self) -> np.ndarray:
        """(6, 4) table in display units, columns as ``calib.params.DH_KEYS`` (theta_deg, d_mm, a_mm,
        alpha_deg)."""
        return np.array([[getattr(j, key) for key in DH_KEYS] for j in self.joints])

    def limits_deg(self) -> np.ndarray:
        return np.array([[j.q_min_deg, j.q_max_deg] for j in self.joints])

    def model(self) -> RobotModel:
        """The robot model the maths uses (internal units: rad, mm)."""
        return RobotModel(
            dh_from_degrees(self.table_deg()), np.array(self.tool_mm), np.radians(self.limits_deg())
        )

    def table_covariance(self, where: str) -> np.ndarray | None:
        """The calibration's (24, 24) table covariance in internal units (rad, mm), as a corrected
        table carries it (``[calibration] covariance``, display units); None if it has none."""
        data = (self.calibration or {}).get("covariance")
        if data is None:
            return None
        names = (self.calibration or {}).get("covariance_parameters", list(DH_NAMES))
        try:
            cov = np.array(data, float)
        except (TypeError, ValueError):
            raise InputError(f"{where}: calibration.covariance: not a table of numbers") from None
        if names != list(DH_NAMES) or cov.shape != (24, 24) or not np.isfinite(cov).all():
            raise InputError(
                f"{where}: calibration.covariance: expected 24 x 24 finite numbers in the order "
                "J1.theta_deg, J1.d_mm, J1.a_mm, J1.alpha_deg, J2.theta_deg, ..."
            )
        factor = display_factor(DH_NAMES)
        return cov / np.outer(factor, factor)


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
    tool sits on the gauge edge (joint-reading noise at the TCP included); ``rho``: line-term weight."""

    drawstring: SetupDrawstring | None = None
    dial: SetupDial | None = None
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
    return validate(RobotFile, read_toml(path), str(path))


def load_setup(path) -> SetupFile:
    return validate(SetupFile, read_toml(path), str(path))
