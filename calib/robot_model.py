"""The robot as the station models it: what compensation and export ask of a robot.

A D-H table, the TCP in the flange frame, the joint limits and the joint-space terms beyond
geometry (``calib.joint_terms``: compliance under gravity, harmonics of a joint's angle), which
change how the controller's readings drive the kinematic chain: everything that asks the model for
poses and Jacobians by the readings (compensation) takes them along, and everything that writes the
chain for another tool (export) can ask which of them the target format cannot hold (``terms``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib import ik
from calib.joint_terms import JointTerms


@dataclass(frozen=True)
class RobotModel:
    """``dh`` (6, 4) D-H table [rad, mm] (columns ``kinematics.DH_COLUMNS``), ``tool`` (3,) TCP in
    the flange frame [mm], ``limits`` (6, 2) joint limits [rad] (lower, upper) of the readings;
    ``terms`` the joint-space terms with their ``term_values`` (K,), internal units (none: a
    geometric model)."""

    dh: np.ndarray
    tool: np.ndarray
    limits: np.ndarray
    terms: JointTerms = field(default_factory=JointTerms)
    term_values: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def link_angles(self, q: np.ndarray) -> np.ndarray:
        """The angles the links take [rad] (N, 6) at readings ``q`` (N, 6) [rad]."""
        return self.terms.link_angles(q, self.term_values, self.terms.basis(q))

    def tool_frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP positions (N, 3) [mm] and tool orientations (N, 3, 3) at readings ``q`` (N, 6) [rad]."""
        return ik.tool_frames(self.dh, self.link_angles(q), self.tool)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """(N, 6, 6) Jacobian of the TCP pose by the readings ``q`` (N, 6) [rad], scaled as
        ``ik.geometric_jacobian``: the chain's at the angles the links take (the terms' own slope by
        the readings, ~1e-4 of it, is left out: Newton needs the direction, the poses are exact)."""
        return ik.geometric_jacobian(self.dh, self.link_angles(q), self.tool)

    def wrist_angle(self, q: np.ndarray) -> np.ndarray:
        """Angle (N,) [rad] between the axes of joints 4 and 6 at ``q`` (N, 6): 0 when singular."""
        return ik.wrist_angle(self.dh, self.link_angles(q))

    def first_outside_limits(self, q: np.ndarray) -> np.ndarray:
        """Index (N,) of the first joint of each configuration ``q`` (N, 6) [rad] outside its
        limits, -1 where all are inside."""
        outside = (q < self.limits[:, 0]) | (q > self.limits[:, 1])
        return np.where(outside.any(axis=1), np.argmax(outside, axis=1), -1)
