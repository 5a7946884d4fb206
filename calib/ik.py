"""Inverse kinematics of a D-H table, batched: damped Newton on the geometric Jacobian.

A target is a TCP position [mm] and a full tool orientation (3x3, base frame). The error of a
configuration is ``(p_target - p, w)`` with ``w`` the rotation vector taking the current
orientation to the target (first order: ``0.5 sum_k r_k x r_target_k``); orientation rows are
scaled by ``LENGTH_SCALE`` so that a milliradian weighs like a millimetre at a metre.
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import base_from_frames

LENGTH_SCALE = 1000.0  # mm per rad
MAX_STEP = 0.2  # rad: a Newton step from far away is cut to this, so it cannot jump branches


def tool_frames(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP positions (N, 3) [mm] and tool orientations (N, 3, 3) for configurations ``q`` (N, 6)."""
    flange = base_from_frames(dh, q)[:, 6]
    return flange[:, :3, :3] @ np.asarray(tool, float) + flange[:, :3, 3], flange[:, :3, :3]


def geometric_jacobian(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """(N, 6, 6) Jacobian of (TCP velocity [mm/rad], angular velocity x ``LENGTH_SCALE``) by ``q``."""
    frames = base_from_frames(dh, q)
    p = frames[:, 6, :3, :3] @ np.asarray(tool, float) + frames[:, 6, :3, 3]
    z, o = frames[:, :6, :3, 2], frames[:, :6, :3, 3]
    linear = np.cross(z, p[:, None, :] - o)
    return np.concatenate([linear, LENGTH_SCALE * z], axis=2).transpose(0, 2, 1)


def conditioning(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """Inverse condition number (N,) of the scaled geometric Jacobian: 0 at a singularity."""
    s = np.linalg.svd(geometric_jacobian(dh, q, tool), compute_uv=False)
    return s[:, -1] / s[:, 0]


def pose_error(
    dh: np.ndarray, tool: np.ndarray, q: np.ndarray, position: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """Scaled error (N, 6) of configurations ``q`` (N, 6) [rad] from the targets: ``position - p``
    [mm] and ``LENGTH_SCALE`` times the rotation vector ``w`` (first order) to ``rotation`` (N, 3, 3)."""
    p, r = tool_frames(dh, q, tool)
    w = 0.5 * np.cross(r.transpose(0, 2, 1), rotation.transpose(0, 2, 1)).sum(axis=1)
    return np.concatenate([position - p, LENGTH_SCALE * w], axis=1)


def solve(
    dh: np.ndarray,
    tool: np.ndarray,
    position: np.ndarray,
    rotation: np.ndarray,
    q_seed: np.ndarray,
    iterations: int = 60,
    damping: float = 1e-2,
    tol: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (N, 6) [rad] reaching ``position`` (N, 3) [mm] with ``rotation`` (N, 3, 3)
    from ``q_seed`` (N, 6), and the remaining scaled error norm (N,) [mm].

    Each iteration takes the damped Newton step ``(J^T J + damping I)^-1 J^T e`` (``J`` the
    ``geometric_jacobian``, ``e`` the ``pose_error``), cut to ``MAX_STEP`` in its largest joint. A
    configuration whose error norm is below ``tol`` [mm] stops moving; the loop ends when all have
    or after ``iterations``.
    """
    q = np.array(q_seed, float)
    err = pose_error(dh, tool, q, position, rotation)
    for _ in range(iterations):
        active = np.linalg.norm(err, axis=1) >= tol
        if not active.any():
            break
        jac = geometric_jacobian(dh, q[active], tool)
        jt = jac.transpose(0, 2, 1)
        step = np.linalg.solve(jt @ jac + damping * np.eye(6), jt @ err[active, :, None])[:, :, 0]
        q[active] += step / np.maximum(1.0, np.abs(step).max(axis=1, keepdims=True) / MAX_STEP)
        err[active] = pose_error(dh, tool, q[active], position[active], rotation[active])
    return q, np.linalg.norm(err, axis=1)
