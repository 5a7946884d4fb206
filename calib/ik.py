"""Inverse kinematics of a D-H table, batched: damped Newton on the geometric Jacobian.

A target is a TCP position [mm] and a full tool orientation (3x3, base frame). The error of a
configuration is ``(p_target - p, w)`` with ``w`` the rotation vector taking the current
orientation to the target (first order: ``0.5 sum_k r_k x r_target_k``); orientation rows are
scaled by ``LENGTH_SCALE`` so that a milliradian weighs like a millimetre at a metre.
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import N_JOINTS, base_from_frames, tool_point

LENGTH_SCALE = 1000.0  # mm per rad
MAX_STEP = 0.2  # rad: a Newton step from far away is cut to this, so it cannot jump branches


def tool_frames(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP positions and tool orientations.

    Parameters
    ----------
    dh, q, tool
        As for :func:`calib.kinematics.tcp_position`.

    Returns
    -------
    position : ndarray, shape (N, 3)
        TCPs in the base frame [mm].
    rotation : ndarray, shape (N, 3, 3)
        The flange's (tool's) orientation in the base frame.
    """
    flange = base_from_frames(dh, q)[:, N_JOINTS]
    return tool_point(flange, tool), flange[:, :3, :3]


def geometric_jacobian(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """Jacobian of the TCP's velocity and the scaled angular velocity by the joint rates.

    Column k is ``(z_k x (p - o_k), LENGTH_SCALE z_k)`` for joint axis ``z_k`` through ``o_k``.

    Parameters
    ----------
    dh, q, tool
        As for :func:`calib.kinematics.tcp_position`.

    Returns
    -------
    ndarray, shape (N, 6, 6)
        Rows: TCP velocity [mm/rad] (3), angular velocity times ``LENGTH_SCALE`` [mm/rad] (3).
    """
    frames = base_from_frames(dh, q)
    p = tool_point(frames[:, N_JOINTS], tool)
    z, o = frames[:, :N_JOINTS, :3, 2], frames[:, :N_JOINTS, :3, 3]
    linear = np.cross(z, p[:, None, :] - o)
    return np.concatenate([linear, LENGTH_SCALE * z], axis=2).transpose(0, 2, 1)


def conditioning(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """Inverse condition number ``s_min / s_max`` of the scaled geometric Jacobian.

    Parameters
    ----------
    Parameters
    ----------
    dh, q, tool
        As for :func:`calib.kinematics.tcp_position`.

    Returns
    -------
    ndarray, shape (N,)
        In [0, 1]: 0 at a singularity.
    """
    s = np.linalg.svd(geometric_jacobian(dh, q, tool), compute_uv=False)
    return s[:, -1] / s[:, 0]


def pose_error(
    dh: np.ndarray, tool: np.ndarray, q: np.ndarray, position: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """Scaled error of configurations from their target poses (module docstring).

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].
    q : ndarray, shape (N, 6)
        Configurations [rad].
    position : ndarray, shape (N, 3)
        Target TCP positions [mm].
    rotation : ndarray, shape (N, 3, 3)
        Target tool orientations.

    Returns
    -------
    ndarray, shape (N, 6)
        ``position - p`` [mm] and ``LENGTH_SCALE`` times the rotation vector ``w`` taking the
        current orientation to the target (first order) [mm].
    """
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
    """Damped Newton from seed configurations to target poses, all at once.

    Each iteration takes the step ``(J^T J + damping I)^-1 J^T e`` (``J`` the
    ``geometric_jacobian``, ``e`` the ``pose_error``), cut to ``MAX_STEP`` in its largest joint. A
    configuration whose error norm is below ``tol`` stops moving; the loop ends when all have or
    after ``iterations``.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].
    position : ndarray, shape (N, 3)
        Target TCP positions [mm].
    rotation : ndarray, shape (N, 3, 3)
        Target tool orientations.
    q_seed : ndarray, shape (N, 6)
        Where each search starts [rad]; the solution is the one this seed converges to.
    iterations : int
        Most Newton steps.
    damping : float
        Levenberg damping of the step (mm^2); larger is steadier near a singularity, less exact.
    tol : float
        Error norm [mm] below which a configuration counts as reached (0: never stop early).

    Returns
    -------
    q : ndarray, shape (N, 6)
        Configurations [rad], not wrapped into any joint limits.
    error : ndarray, shape (N,)
        Remaining scaled error norm [mm]: compare it with a tolerance to know which converged.
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
