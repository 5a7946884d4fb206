"""Batched standard Denavit-Hartenberg kinematics and its analytic parameter Jacobian.

Convention (contract): joint i contributes ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``,
``base_from_flange = A_1 ... A_6`` and the TCP is ``base_from_flange @ [tool, 1]``.

A D-H table is an array ``dh`` of shape (6, 4) whose columns are ``DH_COLUMNS``: theta [rad],
d [mm], a [mm], alpha [rad]. Joint readings ``q`` are (N, 6) in radians. The ``N_DH`` = 24 table
parameters are flattened joint-major (``dh.ravel()``): J1.theta, J1.d, J1.a, J1.alpha, J2.theta, ...
This is the project's one D-H implementation (the simulator computes with it too); the tests
check it against a second formulation and finite differences.

Two compositions of the same frames: ``base_from_frames`` multiplies (4, 4) transforms row by row
(what ``tcp_position``, ``tcp_jacobian``, the inverse kinematics, planning and the simulator use);
``frame_axes`` composes the axes column by column on all rows at once, and ``tcp_position_by_axes`` /
``tcp_jacobian_by_axes`` on top of it are 6-9x faster on many rows (the calibration's fits). The
two differ in the last digits only, but a plan's choices turn on those: planning keeps the products.
"""

from __future__ import annotations

import numpy as np

from calib.blocks import each_block

DH_COLUMNS = ("theta", "d", "a", "alpha")
THETA, D, A, ALPHA = range(4)
N_JOINTS = 6
N_DH = N_JOINTS * len(DH_COLUMNS)
"""Number of D-H table parameters: they lead every parameter vector ``x`` (``dh_table(x)``)."""
KINEMATICS_ROWS = 8192
"""Rows per block of ``tcp_position_by_axes`` and ``tcp_jacobian_by_axes``: a block's frames stay a
few MB (on 100,000 rows, whole-array frames cost more in page faults than in arithmetic)."""


def dh_table(x: np.ndarray) -> np.ndarray:
    """The D-H table at the head of a parameter vector.

    Parameters
    ----------
    x : ndarray, shape (n,), n >= N_DH
        Parameter vector whose first ``N_DH`` entries are the table, joint-major.

    Returns
    -------
    ndarray, shape (6, 4)
        The table (columns ``DH_COLUMNS``, internal units); a view of ``x`` where ``x`` is an array.
    """
    return np.asarray(x)[:N_DH].reshape(N_JOINTS, len(DH_COLUMNS))


def joint_transforms(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Link transforms ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``.

    Parameters
    ----------
    dh : ndarray, shape (k, 4)
        D-H rows (theta [rad], d [mm], a [mm], alpha [rad]); k = 6 for a whole arm.
    q : ndarray, shape (N, k) or (k,)
        Joint readings [rad].

    Returns
    -------
    ndarray, shape (N, k, 4, 4)
        Frame i-1 from frame i for every configuration and joint, translations in mm.
    """
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


def frame_axes(dh: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The axes and origins of the D-H frames 0..6 in the base frame, coordinate-major.

    Composes ``A_1 ... A_i`` column by column (frame i's x is ``cos(theta) x + sin(theta) y`` of frame
    i-1, and so on) on arrays of all rows at once, instead of a (4, 4) product per row. ``dh`` (6, 4)
    and ``q`` (N, 6) as for ``base_from_frames``; returns the unit axes ``x, y, z`` and the origins
    ``o`` [mm] of frames 0..6 (0 the base, 6 the flange), each (7, 3, N).
    """
    q = np.atleast_2d(q)
    theta = (dh[:, THETA] + q).T  # (6, N)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(dh[:, ALPHA]), np.sin(dh[:, ALPHA])
    x, y, z, o = (np.empty((N_JOINTS + 1, 3, q.shape[0])) for _ in range(4))
    for axis, k in ((x, 0), (y, 1), (z, 2)):
        axis[0] = np.eye(3)[:, k, None]
    o[0] = 0.0
    for i in range(N_JOINTS):
        u = x[i] * ct[i] + y[i] * st[i]
        v = y[i] * ct[i] - x[i] * st[i]
        x[i + 1] = u
        y[i + 1] = v * ca[i] + z[i] * sa[i]
        z[i + 1] = z[i] * ca[i] - v * sa[i]
        o[i + 1] = o[i] + dh[i, A] * u + dh[i, D] * z[i]
    return x, y, z, o


def base_from_frames(dh: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Poses of the D-H frames 0..6 in the base frame: ``A_1 ... A_i``.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    q : ndarray, shape (N, 6) or (6,)
        Joint readings [rad].

    Returns
    -------
    ndarray, shape (N, 7, 4, 4)
        ``base_from_frame_i``, translations in mm; frame 0 is the identity, frame 6 the flange.
    """
    links = joint_transforms(dh, q)
    frames = np.empty((links.shape[0], N_JOINTS + 1, 4, 4))
    frames[:, 0] = np.eye(4)
    for i in range(N_JOINTS):
        frames[:, i + 1] = frames[:, i] @ links[:, i]
    return frames


def tool_point(base_from_flange: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """The TCP ``base_from_flange @ [tool, 1]``.

    Parameters
    ----------
    base_from_flange : ndarray, shape (N, 4, 4)
        Flange poses, translations in mm.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].

    Returns
    -------
    ndarray, shape (N, 3)
        TCP positions in the base frame [mm].
    """
    return base_from_flange[:, :3, :3] @ np.asarray(tool, float) + base_from_flange[:, :3, 3]


def tcp_position(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """TCP positions in the base frame.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    q : ndarray, shape (N, 6) or (6,)
        Joint readings [rad].
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].

    Returns
    -------
    ndarray, shape (N, 3)
        TCP positions [mm]; ``KINEMATICS_ROWS`` rows at a time (the same products, row by row,
        without every row's seven frames at once: a million rows' are some 900 MB).
    """
    q = np.atleast_2d(q)
    p = np.empty((q.shape[0], 3))
    for s in range(0, q.shape[0], KINEMATICS_ROWS):
        p[s : s + KINEMATICS_ROWS] = tool_point(
            base_from_frames(dh, q[s : s + KINEMATICS_ROWS])[:, N_JOINTS], tool
        )
    return p


def tcp_jacobian(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP positions and their derivatives by the table parameters ``dh.ravel()``.

    Each parameter moves the TCP as a rigid screw of the links after it:

    - theta_i: rotation about ``z_{i-1}`` through ``o_{i-1}``: ``z_{i-1} x (p - o_{i-1})``
    - d_i: translation along ``z_{i-1}``: ``z_{i-1}``
    - a_i: translation along ``x_i``: ``x_i``
    - alpha_i: rotation about ``x_i`` through ``o_i``: ``x_i x (p - o_i)``

    Parameters
    ----------
    dh, q, tool
        As for :func:`tcp_position`.

    Returns
    -------
    p : ndarray, shape (N, 3)
        TCP positions [mm].
    jac : ndarray, shape (N, 3, N_DH)
        ``dp / d dh.ravel()``: mm/rad for the angles, mm/mm for the lengths.
    """
    frames = base_from_frames(dh, q)
    p = tool_point(frames[:, N_JOINTS], tool)
    z_prev, o_prev = frames[:, :N_JOINTS, :3, 2], frames[:, :N_JOINTS, :3, 3]  # (N, 6, 3)
    x_this, o_this = frames[:, 1:, :3, 0], frames[:, 1:, :3, 3]
    jac = np.empty((p.shape[0], 3, N_JOINTS, len(DH_COLUMNS)))
    jac[:, :, :, THETA] = np.cross(z_prev, p[:, None, :] - o_prev).transpose(0, 2, 1)
    jac[:, :, :, D] = z_prev.transpose(0, 2, 1)
    jac[:, :, :, A] = x_this.transpose(0, 2, 1)
    jac[:, :, :, ALPHA] = np.cross(x_this, p[:, None, :] - o_this).transpose(0, 2, 1)
    return p, jac.reshape(p.shape[0], 3, N_DH)


def tcp_position_by_axes(dh: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """``tcp_position`` composed by ``frame_axes``, ``KINEMATICS_ROWS`` rows at a time (N, 3) [mm]."""
    q = np.atleast_2d(q)
    p = np.empty((3, q.shape[0]))

    def block(s: int, e: int) -> None:
        p[:, s:e] = _flange_point(*frame_axes(dh, q[s:e]), tool)

    each_block(q.shape[0], KINEMATICS_ROWS, block)
    return p.T


def _flange_point(x, y, z, o, tool) -> np.ndarray:
    """The TCP (3, N) [mm] of ``frame_axes``'s flange frame and the tool (3,) [mm]."""
    t = np.asarray(tool, float)
    return x[N_JOINTS] * t[0] + y[N_JOINTS] * t[1] + z[N_JOINTS] * t[2] + o[N_JOINTS]


def tcp_jacobian_by_axes(
    dh: np.ndarray, q: np.ndarray, tool: np.ndarray, out: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``tcp_jacobian`` composed by ``frame_axes``, ``KINEMATICS_ROWS`` rows at a time: TCPs (N, 3)
    [mm] and their derivatives (N, 3, N_DH) by ``dh.ravel()``, a view of ``out[:, :, :N_DH]``
    (``out`` (3, N, >= N_DH), coordinate-major, as a model's chain rule reads them; default new)."""
    q = np.atleast_2d(q)
    p = np.empty((3, q.shape[0]))
    out = np.empty((3, q.shape[0], N_DH)) if out is None else out
    jac = out[:, :, :N_DH].reshape(3, q.shape[0], N_JOINTS, len(DH_COLUMNS))  # coordinate, row, joint, column

    def block(s: int, e: int) -> None:
        x, y, z, o = frame_axes(dh, q[s:e])
        p[:, s:e] = pb = _flange_point(x, y, z, o, tool)
        jac[:, s:e, :, THETA] = _cross(z[:N_JOINTS], pb - o[:N_JOINTS]).transpose(1, 2, 0)
        jac[:, s:e, :, D] = z[:N_JOINTS].transpose(1, 2, 0)
        jac[:, s:e, :, A] = x[1:].transpose(1, 2, 0)
        jac[:, s:e, :, ALPHA] = _cross(x[1:], pb - o[1:]).transpose(1, 2, 0)

    each_block(q.shape[0], KINEMATICS_ROWS, block)
    return p.T, out[:, :, :N_DH].transpose(1, 0, 2)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` of (k, 3, N) vectors along axis 1."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def parallel_axis_pairs(dh: np.ndarray, tol_rad: float = 1e-6) -> list[int]:
    """Joints whose axis is parallel to the next one's: ``|sin(alpha_i)| < tol_rad``.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    tol_rad : float
        How close to 0 or pi ``alpha_i`` must be [rad].

    Returns
    -------
    list of int
        0-based indices ``i`` (0..4) of the joints whose axis is parallel to joint ``i + 1``'s.
    """
    return [i for i in range(N_JOINTS - 1) if abs(np.sin(dh[i, ALPHA])) < tol_rad]
