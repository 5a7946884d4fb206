"""Inverse kinematics of a D-H table, batched: damped Newton on the geometric Jacobian.

A target is a TCP position [mm] and a full tool orientation (3x3, base frame). The error of a
configuration is ``(p_target - p, w)`` with ``w`` the rotation vector taking the current
orientation to the target (first order: ``0.5 sum_k r_k x r_target_k``); orientation rows are
scaled by ``LENGTH_SCALE`` so that a milliradian weighs like a millimetre at a metre.
"""

from __future__ import annotations

from dataclasses import dataclass

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
) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (N, 6) [rad] reaching ``position`` (N, 3) [mm] with ``rotation`` (N, 3, 3)
    from ``q_seed`` (N, 6), and the remaining scaled error norm (N,) [mm]."""
    found = solve_pose(
        lambda q: tool_frames(dh, q, tool),
        lambda q: geometric_jacobian(dh, q, tool),
        position,
        rotation,
        q_seed,
        NewtonOptions(iterations=iterations, damping=damping),
    )
    return found.q, np.hypot(found.position_error, LENGTH_SCALE * found.orientation_error)


@dataclass(frozen=True, kw_only=True)
class NewtonOptions:
    """``iterations``: most Newton steps; ``damping``: added to ``J^T J`` (scaled units, mm^2);
    ``position_tol`` [mm] / ``orientation_tol`` [rad]: a row within both stops (None: every row
    runs every iteration)."""

    iterations: int = 60
    damping: float = 1e-2
    position_tol: float | None = None
    orientation_tol: float | None = None


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
    """Rows (N,) of a scaled pose error within both tolerances (none without tolerances)."""
    if options.position_tol is None or options.orientation_tol is None:
        return np.zeros(len(err), bool)
    pos, rot = _split(err)
    return (pos <= options.position_tol) & (rot <= options.orientation_tol)
