"""Batched standard Denavit-Hartenberg kinematics and its analytic parameter Jacobian.

Convention (contract): joint i contributes ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``,
``base_from_flange = A_1 ... A_6`` and the TCP is ``base_from_flange @ [tool, 1]``.

A D-H table is an array ``dh`` of shape (6, 4) whose columns are ``DH_COLUMNS``: theta [rad],
d [mm], a [mm], alpha [rad]. Joint readings ``q`` are (N, 6) in radians. The 24 table parameters
are flattened joint-major (``dh.ravel()``): J1.theta, J1.d, J1.a, J1.alpha, J2.theta, ...
"""

from __future__ import annotations

import numpy as np

DH_COLUMNS = ("theta", "d", "a", "alpha")
THETA, D, A, ALPHA = range(4)
N_JOINTS = 6
N_DH = N_JOINTS * len(DH_COLUMNS)
"""Number of D-H table parameters: they lead every parameter vector ``x`` (``dh_table(x)``)."""


def dh_table(x: np.ndarray) -> np.ndarray:
    """The D-H table (6, 4) that leads a parameter vector ``x`` (its first ``N_DH`` entries), in
    internal units."""
    return np.asarray(x)[:N_DH].reshape(N_JOINTS, len(DH_COLUMNS))


def joint_transforms(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Link transforms ``A_i`` for every sample, shape (N, 6, 4, 4)."""
    q = np.atleast_2d(q)
    theta = dh[:, THETA] + q
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(dh[:, ALPHA]), np.sin(dh[:, ALPHA])
    a, d = dh[:, A], dh[:, D]
    out = np.zeros(q.shape + (4, 4))
    out[..., 0, 0] = ct
    out[..., 0, 1] = -st * ca
    out[..., 0, 2] = st * sa
    out[..., 0, 3] = a * ct
    out[..., 1, 0] = st
    out[..., 1, 1] = ct * ca
    out[..., 1, 2] = -ct * sa
    out[..., 1, 3] = a * st
    out[..., 2, 1] = sa
    out[..., 2, 2] = ca
    out[..., 2, 3] = d
    out[..., 3, 3] = 1.0
    return out


def base_from_frames(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Poses of D-H frames 0..6 in the base frame, shape (N, 7, 4, 4); frame 0 is the identity."""
    links = joint_transforms(dh, q)
    frames = np.empty((links.shape[0], 7, 4, 4))
    frames[:, 0] = np.eye(4)
    for i in range(6):
        frames[:, i + 1] = frames[:, i] @ links[:, i]
    return frames


def tcp_position(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """TCP positions in the base frame [mm], shape (N, 3)."""
    flange = base_from_frames(dh, q)[:, 6]
    return flange[:, :3, :3] @ np.asarray(tool, float) + flange[:, :3, 3]


def tcp_jacobian(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP positions (N, 3) and their derivatives with respect to ``dh.ravel()``, (N, 3, 24).

    Each parameter moves the TCP as a rigid screw of the links after it:

    - theta_i: rotation about ``z_{i-1}`` through ``o_{i-1}``: ``z_{i-1} x (p - o_{i-1})``
    - d_i: translation along ``z_{i-1}``: ``z_{i-1}``
    - a_i: translation along ``x_i``: ``x_i``
    - alpha_i: rotation about ``x_i`` through ``o_i``: ``x_i x (p - o_i)``
    """
    frames = base_from_frames(dh, q)
    flange = frames[:, 6]
    p = flange[:, :3, :3] @ np.asarray(tool, float) + flange[:, :3, 3]
    z_prev, o_prev = frames[:, :6, :3, 2], frames[:, :6, :3, 3]  # (N, 6, 3)
    x_this, o_this = frames[:, 1:, :3, 0], frames[:, 1:, :3, 3]
    jac = np.empty((p.shape[0], 3, 6, 4))
    jac[:, :, :, THETA] = np.cross(z_prev, p[:, None, :] - o_prev).transpose(0, 2, 1)
    jac[:, :, :, D] = z_prev.transpose(0, 2, 1)
    jac[:, :, :, A] = x_this.transpose(0, 2, 1)
    jac[:, :, :, ALPHA] = np.cross(x_this, p[:, None, :] - o_this).transpose(0, 2, 1)
    return p, jac.reshape(p.shape[0], 3, N_DH)


def parallel_axis_pairs(dh: np.ndarray, tol_rad: float = 1e-6) -> list[int]:
    """Joints ``i`` (0-based) whose axis is parallel to the next one's (alpha_i = 0 or pi)."""
    return [i for i in range(5) if abs(np.sin(dh[i, ALPHA])) < tol_rad]
