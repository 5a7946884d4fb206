"""The robot as the station models it: what compensation and export ask of a robot.

Today the model is geometric: a D-H table, the TCP in the flange frame and the joint limits. Terms
beyond geometry (joint compliance, joint-angle harmonics) change how the controller's readings
drive the kinematic chain; they belong here, so that everything asking a model for poses and
Jacobians by the readings (compensation) takes them along, and everything that writes the chain
for another tool (export) can ask which of them the target format cannot hold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib import ik


@dataclass(frozen=True)
class RobotModel:
    """``dh`` (6, 4) D-H table [rad, mm] (columns ``kinematics.DH_COLUMNS``), ``tool`` (3,) TCP in
    the flange frame [mm], ``limits`` (6, 2) joint limits [rad] (lower, upper)."""

    dh: np.ndarray
    tool: np.ndarray
    limits: np.ndarray

    def tool_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP positions (N, 3) [mm] and tool orientations (N, 3, 3) at readings ``q`` (N, 6) [rad]."""
        return ik.tool_frames(self.dh, q, self.tool)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """(N, 6, 6) Jacobian of the TCP pose by the readings ``q`` (N, 6) [rad], scaled as
        ``ik.geometric_jacobian``."""
        return ik.geometric_jacobian(self.dh, q, self.tool)

    def wrist_angle(self, q: np.ndarray) -> np.ndarray:
        """Angle (N,) [rad] between the axes of joints 4 and 6 at ``q`` (N, 6): 0 when singular."""
        return ik.wrist_angle(self.dh, q)

    def first_outside_limits(self, q: np.ndarray) -> np.ndarray:
        """Index (N,) of the first joint of each configuration ``q`` (N, 6) [rad] outside its
        limits, -1 where all are inside."""
        outside = (q < self.limits[:, 0]) | (q > self.limits[:, 1])
        return np.where(outside.any(axis=1), np.argmax(outside, axis=1), -1)
