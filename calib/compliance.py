"""Joint compliance under a load at the TCP: joints 2 and 3 yield by an angle proportional to the
gravity torque a load at the TCP puts on them, the standard deflection term of robot calibration
(an arm's sag with its reach)::

    dq_j = c_j lever_j(q),   lever_j = z_j . ((p - o_j) x g)   [m],

``lever_j`` the torque of a 1 N load at the TCP ``p`` about joint j's axis (``calib.joint_terms.
gravity_torques``, gravity along the base frame's -z: a floor-mounted robot) and ``c_j`` [rad per
m] the joint's compliance times the load. Joint 2's lever changes with joints 2 and 3, joint 3's
with their sum, so no function of a joint's own angle (``calib.angle_errors``) expresses it, and
the table expresses part of its shape only (``calib.absorbed_angles`` fits it beside the table).
Unlike ``calib.joint_terms``' compliances it needs no link masses: the load is wherever the arm's
weight and payload put it, lumped at the TCP.
"""

from __future__ import annotations

import numpy as np

from calib.joint_terms import G_MS2, LinkMasses, gravity_torques
from calib.kinematics import N_JOINTS, THETA

COMPLIANT_JOINTS = (1, 2)
"""Joints (0-based) that yield under the load: 2 and 3, the arm's pitch joints."""
COMPLIANCE_PRIOR = 3e-4
"""Prior RMS of a compliance [rad per m of lever arm]: 0.3 mm at 1 m from a 1 m lever, the size of
an industrial arm's gravity deflection."""


def gravity_lever_m(dh: np.ndarray, q: np.ndarray, tool_mm: np.ndarray) -> np.ndarray:
    """The lever arm (N, 2) [m] of a load at the TCP ``tool_mm`` (3,) [mm, flange frame] about the
    axes of ``COMPLIANT_JOINTS``, table ``dh`` (6, 4) (rad, mm), readings ``q`` (N, 6) [rad]."""
    load = LinkMasses(np.zeros(N_JOINTS), np.zeros((N_JOINTS, 3))).with_payload(1.0 / G_MS2, tool_mm)
    return gravity_torques(dh, q, load, COMPLIANT_JOINTS)


def compliance_response(
    dh: np.ndarray, q: np.ndarray, tool_mm: np.ndarray, jacobian: np.ndarray
) -> np.ndarray:
    """The TCP's move (N, 3, 2) [mm per rad/m] per unit of each compliance: its derivative by the
    joint's angle (``jacobian`` (N, 3, N_DH) of the table, ``calib.kinematics.tcp_jacobian``)
    times the joint's ``gravity_lever_m``."""
    lever = gravity_lever_m(dh, q, tool_mm)
    return jacobian[:, :, [4 * j + THETA for j in COMPLIANT_JOINTS]] * lever[:, None, :]


def compliance_turn_rad(
    dh: np.ndarray, q: np.ndarray, tool_mm: np.ndarray, compliance: np.ndarray
) -> np.ndarray:
    """The readings ``q`` (N, 6) [rad] turned by the compliances ``compliance`` (2,) [rad per m]
    at their lever arms: the angles the links take."""
    out = np.array(q, float)
    out[:, list(COMPLIANT_JOINTS)] += gravity_lever_m(dh, q, tool_mm) * compliance
    return out
