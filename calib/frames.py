"""A D-H table as the joint origins of a kinematic tree (URDF, Universal Robots' ``kinematics:``).

A URDF-style chain places each revolute joint at a fixed ``origin`` in its parent link and turns
about the joint's z axis by the reading: ``base_from_flange = O_1 Rz(q_1) O_2 Rz(q_2) ... O_6
Rz(q_6) O_7``. Regrouping the contract's ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
gives the origins (``a_0 = alpha_0 = 0``)::

    O_i = Tx(a_{i-1}) Rx(alpha_{i-1}) Rz(theta_i) Tz(d_i),   i = 1..6
    O_7 = Tx(a_6) Rx(alpha_6)                                (last joint to the D-H flange frame)

so the table's theta offsets sit in the origins and the joints take the controller's readings.

Orientations are written as URDF roll-pitch-yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes
x, y, z), pitch in [-pi/2, pi/2].
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import ALPHA, THETA, A, D

GIMBAL_TOL = 1e-12
"""``|cos(pitch)|`` below which roll and yaw turn about the same axis: yaw is then set to 0."""


def rot_x(angle: float) -> np.ndarray:
    """Homogeneous rotation (4, 4) by ``angle`` [rad] about x."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.eye(4)
    out[1:3, 1:3] = [[c, -s], [s, c]]
    return out


def rot_z(angle: float) -> np.ndarray:
    """Homogeneous rotation (4, 4) by ``angle`` [rad] about z."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.eye(4)
    out[:2, :2] = [[c, -s], [s, c]]
    return out


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """Homogeneous translation (4, 4) by (x, y, z)."""
    out = np.eye(4)
    out[:3, 3] = x, y, z
    return out


def joint_origins(dh: np.ndarray) -> np.ndarray:
    """Origins ``O_1 .. O_7`` (7, 4, 4) of the D-H table ``dh`` (6, 4) [rad, mm], lengths in mm.

    ``O_i`` (i = 1..6) is joint i's origin in the link before it, ``O_7`` the D-H flange frame
    (frame 6) in the last joint's link; composing ``O_1 Rz(q_1) ... O_6 Rz(q_6) O_7`` gives
    ``base_from_flange`` of the contract's D-H chain.
    """
    out = np.empty((7, 4, 4))
    a_prev, alpha_prev = 0.0, 0.0
    for i in range(6):
        theta, d = dh[i, THETA], dh[i, D]
        out[i] = translation(x=a_prev) @ rot_x(alpha_prev) @ rot_z(theta) @ translation(z=d)
        a_prev, alpha_prev = dh[i, A], dh[i, ALPHA]
    out[6] = translation(x=a_prev) @ rot_x(alpha_prev)
    return out


def chain_pose(origins: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``O_1 Rz(q_1) ... O_6 Rz(q_6) O_7`` (4, 4) for one configuration ``q`` (6,) [rad]."""
    pose = origins[0] @ rot_z(q[0])
    for i in range(1, 6):
        pose = pose @ origins[i] @ rot_z(q[i])
    return pose @ origins[6]


def matrix_from_rpy(rpy) -> np.ndarray:
    """Rotation (3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)`` of URDF angles ``rpy`` = (roll, pitch, yaw) [rad]."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def rpy_from_matrix(rot: np.ndarray) -> np.ndarray:
    """URDF angles (roll, pitch, yaw) [rad] of a rotation (3, 3), pitch in [-pi/2, pi/2].

    With ``R = Rz(yaw) Ry(pitch) Rx(roll)``: ``R_20 = -sin(pitch)`` and ``(R_10, R_00) =
    cos(pitch) (sin(yaw), cos(yaw))``; roll is then read from ``Rx(roll) = (Rz(yaw) Ry(pitch))^T R``,
    so that near ``cos(pitch) = 0``, where roll and yaw turn about nearly the same axis and yaw is
    ill-determined, roll takes up whatever yaw got wrong and the angles still give ``R``. At
    ``cos(pitch) = 0`` only ``yaw -+ roll`` is defined: yaw is set to 0.
    """
    rot = np.asarray(rot, float)
    cos_pitch = np.hypot(rot[0, 0], rot[1, 0])
    pitch = np.arctan2(-rot[2, 0], cos_pitch)
    yaw = 0.0 if cos_pitch < GIMBAL_TOL else np.arctan2(rot[1, 0], rot[0, 0])
    rest = (rot_z(yaw)[:3, :3] @ matrix_from_rpy((0.0, pitch, 0.0))).T @ rot
    return np.array([np.arctan2(rest[2, 1], rest[1, 1]), pitch, yaw])
