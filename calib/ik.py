"""Inverse kinematics of a D-H table, batched: damped Newton on the geometric Jacobian.

A target is a TCP position [mm] and a full tool orientation (3x3, base frame). The error of a
configuration is ``(p_target - p, w)`` with ``w`` the rotation vector taking the current
orientation to the target (first order: ``0.5 sum_k r_k x r_target_k``); orientation rows are
scaled by ``LENGTH_SCALE`` so that a milliradian weighs like a millimetre at a metre.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def wrist_angle(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angle (N,) [rad, 0..pi/2] between the axes of joints 4 and 6: 0 at the wrist singularity,
    where turning joint 4 and joint 6 oppositely moves nothing."""
    frames = base_from_frames(dh, q)
    z4, z6 = frames[:, 3, :3, 2], frames[:, 5, :3, 2]
    return np.arctan2(np.linalg.norm(np.cross(z4, z6), axis=1), np.abs(np.sum(z4 * z6, axis=1)))


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

    :func:`solve_pose` on this table: each iteration takes the step
    ``(J^T J + damping I)^-1 J^T e`` (``J`` the ``geometric_jacobian``, ``e`` the ``pose_error``),
    cut to ``MAX_STEP`` in its largest joint. A configuration whose error norm is below ``tol``
    stops moving; the loop ends when all have or after ``iterations``.

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
    found = solve_pose(
        lambda q: tool_frames(dh, q, tool),
        lambda q: geometric_jacobian(dh, q, tool),
        position,
        rotation,
        q_seed,
        NewtonOptions(iterations=iterations, damping=damping, tol=tol),
    )
    return found.q, np.hypot(found.position_error, LENGTH_SCALE * found.orientation_error)


@dataclass(frozen=True, kw_only=True)
class NewtonOptions:
    """``iterations``: most Newton steps; ``damping``: added to ``J^T J`` (scaled units, mm^2);
    ``position_tol`` [mm] / ``orientation_tol`` [rad]: a row within both stops (None: every row
    runs every iteration); ``tol`` [mm]: a row whose scaled error norm is below it stops (0: none)."""

    iterations: int = 60
    damping: float = 1e-2
    position_tol: float | None = None
    orientation_tol: float | None = None
    tol: float = 0.0


@dataclass(frozen=True)
class PoseSolution:
    """Configurations ``q`` (N, 6) [rad], what is left of each row's error: TCP position [mm] and
    orientation [rad] (N,), and the Newton steps taken (by the slowest row)."""

    q: np.ndarray
    position_error: np.ndarray
    orientation_error: np.ndarray
    iterations: int


def pose_error(frames, q, position, rotation) -> np.ndarray:
    """(N, 6) error of configurations ``q``: ``position - p`` [mm] and ``LENGTH_SCALE`` times the
    rotation vector (first order) from the reached orientation to ``rotation``."""
    p, r = frames(q)
    w = 0.5 * np.cross(r.transpose(0, 2, 1), rotation.transpose(0, 2, 1)).sum(axis=1)
    return np.concatenate([position - p, LENGTH_SCALE * w], axis=1)


def solve_pose(
    frames, jacobian, position, rotation, q_seed, options: NewtonOptions = NewtonOptions()
) -> PoseSolution:
    """Damped Newton on the full TCP pose of any robot model, batched.

    ``frames(q)`` gives TCP positions (N, 3) [mm] and orientations (N, 3, 3), ``jacobian(q)`` their
    (N, 6, 6) Jacobian by the readings (scaled as :func:`geometric_jacobian`). Each step solves
    ``(J^T J + damping I) dq = J^T e`` and is cut to ``MAX_STEP`` per joint, so a row moves
    continuously from its seed ``q_seed`` (N, 6) [rad] and keeps its branch; a row within the
    tolerances stops there while the others go on.
    """
    q = np.array(q_seed, float)
    err = pose_error(frames, q, position, rotation)
    active = ~_within(err, options)
    done = 0
    while done < options.iterations and active.any():
        rows = np.flatnonzero(active)
        jac = jacobian(q[rows])
        jt = jac.transpose(0, 2, 1)
        rhs = jt @ err[rows, :, None]
        step = np.linalg.solve(jt @ jac + options.damping * np.eye(6), rhs)[:, :, 0]
        q[rows] += step / np.maximum(1.0, np.abs(step).max(axis=1, keepdims=True) / MAX_STEP)
        err[rows] = pose_error(frames, q[rows], position[rows], rotation[rows])
        active[rows] = ~_within(err[rows], options)
        done += 1
    pos, rot = _split(err)
    return PoseSolution(q, pos, rot, done)


def _split(err: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position [mm] and orientation [rad] error norms (N,) of a scaled (N, 6) pose error."""
    return np.linalg.norm(err[:, :3], axis=1), np.linalg.norm(err[:, 3:], axis=1) / LENGTH_SCALE


def _within(err: np.ndarray, options: NewtonOptions) -> np.ndarray:
    """Rows (N,) of a scaled pose error below ``tol`` or within both tolerances."""
    within = np.linalg.norm(err, axis=1) < options.tol
    if options.position_tol is None or options.orientation_tol is None:
        return within
    pos, rot = _split(err)
    return within | ((pos <= options.position_tol) & (rot <= options.orientation_tol))
