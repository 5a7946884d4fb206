"""What a calibration promises away from its samples: parameter covariance pushed to the TCP.

The TCP error field of a table error ``dx`` over configurations is ``J dx`` (``J`` the stacked TCP
Jacobians, (3N, 24)). Re-registering the base absorbs any rigid motion ``t + w x p``, so the part
of ``J`` in that 6-dimensional span is removed first::

    J_perp = (I - B B^+) J,        predicted RMS = sqrt(trace(J_perp C J_perp^T) / N)

with ``B`` (3N, 6) the rigid displacement fields at the nominal TCPs and ``C`` (r, r) the robot's
covariance (the table, then its joint-space terms: ``calib.joint_terms``): the fit's covariance for
identified parameters, plus what each held parameter's prior (a table parameter's manufacturing
tolerance) does to the TCP and, through the fit, to the identified ones.

That is an expectation. One calibration's actual error is ``sum_i lambda_i z_i^2`` (squared RMS),
``lambda_i`` the eigenvalues of ``C^1/2 J_perp^T J_perp C^1/2 / N`` and ``z_i`` standard normal: when
a few weak directions dominate (one gauge line) it scatters widely about the expectation, so a
bound is given too (Welch-Satterthwaite: a scaled chi-square with the same mean and variance).
"""

from __future__ import annotations

import numpy as np

from calib.joint_terms import JointTerms
from calib.kinematics import base_from_frames
from calib.special import gammaincinv


def rigid_fields(p: np.ndarray) -> np.ndarray:
    """Displacement fields of a rigid motion at points: unit translations and small rotations about
    the points' centroid ``c`` (``w x (p - c)`` for unit ``w``).

    Parameters
    ----------
    p : ndarray, shape (N, 3)
        Points [mm].

    Returns
    -------
    ndarray, shape (3N, 6)
        Columns: translation along x, y, z [mm/mm], rotation about x, y, z [mm/rad]; rows point-major.
    """
    rel = p - p.mean(axis=0)
    fields = np.zeros((p.shape[0], 3, 6))
    fields[:, :, :3] = np.eye(3)
    for k in range(3):
        fields[:, :, 3 + k] = np.cross(np.eye(3)[k], rel)
    return fields.reshape(-1, 6)


def workspace_error_modes(
    dh: np.ndarray,
    tool: np.ndarray,
    q: np.ndarray,
    cov: np.ndarray,
    terms: JointTerms | None = None,
    tool_fitted: bool = False,
    left: np.ndarray | None = None,
) -> np.ndarray:
    """Variances of the independent modes of the TCP error field after a rigid re-fit of the base:
    the eigenvalues of ``C^1/2 J_perp^T J_perp C^1/2 / N`` (module docstring); with ``left``, each
    configuration's field scaled by the root of its share of the error left there.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].
    q : ndarray, shape (N, 6)
        Configurations over which the error is averaged [rad].
    cov : ndarray, shape (r, r)
        Covariance of the error of the table (24), the TCP in the flange frame (3, only where
        ``tool_fitted``), then ``terms`` (K), internal units.
    terms : JointTerms, optional
        The robot's joint-space terms (default: none), linearised at zero.
    tool_fitted : bool
        Whether ``cov`` covers the TCP's flange coordinates (a calibration that fitted them).
    left : ndarray, shape (N,), optional
        Share (0-1) of the table's error variance left at each configuration (a residual map's,
        ``calib.residual_map.left_share``: small near the rows it learnt from, 1 far from them).

    Returns
    -------
    ndarray, shape (r,)
        Mode variances [mm^2], descending, >= 0; their sum is the expected squared RMS error.
    """
    a_perp = _non_rigid_fields(dh, tool, q, terms, tool_fitted)
    if left is not None:
        a_perp = a_perp * np.repeat(np.sqrt(left), 3)[:, None]
    s, u = np.linalg.eigh(cov)
    root = u * np.sqrt(np.clip(s, 0.0, None))
    field = a_perp @ root
    return np.clip(np.linalg.eigvalsh(field.T @ field / len(q))[::-1], 0.0, None)


def parameter_workspace_rms(
    dh: np.ndarray, tool: np.ndarray, q: np.ndarray, terms: JointTerms | None = None
) -> np.ndarray:
    """How far a unit change of each parameter alone moves the TCP, RMS over configurations, after
    a rigid re-fit of the base (``J_perp``'s column norms over ``sqrt(N)``).

    Parameters
    ----------
    dh, tool, q, terms
        As ``workspace_error_modes``.

    Returns
    -------
    ndarray, shape (24 + K,)
        [mm per internal unit] for the table's parameters, then the terms'.
    """
    a_perp = _non_rigid_fields(dh, tool, q, terms, False)
    return np.sqrt(np.sum(a_perp**2, axis=0) / len(q))


def _non_rigid_fields(dh, tool, q, terms: JointTerms | None, tool_fitted: bool) -> np.ndarray:
    """The TCP Jacobian (3N, 24 [+ 3] + K) by the table, the flange TCP (``tool_fitted``) and the
    terms, with its part in the rigid motions of the base taken out."""
    terms = terms or JointTerms()
    basis = terms.basis(q)
    p, jac_table, jac_terms = terms.tcp_jacobian(dh, q, tool, np.zeros(len(terms)), basis)
    jac_tool = base_from_frames(dh, q)[:, -1, :3, :3] if tool_fitted else np.zeros((len(q), 3, 0))
    a = np.concatenate([jac_table, jac_tool, jac_terms], axis=2).reshape(3 * len(q), -1)
    q_rigid = np.linalg.qr(rigid_fields(p))[0]
    return a - q_rigid @ (q_rigid.T @ a)


def predicted_workspace_rmse(modes: np.ndarray) -> float:
    """Expected RMS TCP error: the root of the summed mode variances.

    Parameters
    ----------
    modes : ndarray, shape (k,)
        Mode variances [mm^2] (``workspace_error_modes``).

    Returns
    -------
    float
        RMS error [mm].
    """
    return float(np.sqrt(modes.sum()))


def workspace_rmse_bound(modes: np.ndarray, probability: float = 0.95) -> float:
    """RMS TCP error that one calibration stays below with ``probability``: the quantile of
    ``sum lambda_i z_i^2`` as a scaled chi-square with ``(sum lambda)^2 / sum lambda^2`` degrees of
    freedom and the same mean.

    Parameters
    ----------
    modes : ndarray, shape (k,)
        Mode variances ``lambda_i`` [mm^2] (``workspace_error_modes``).
    probability : float
        In (0, 1).

    Returns
    -------
    float
        The bound [mm]; 0 when every mode is 0.
    """
    total = modes.sum()
    if total <= 0.0:
        return 0.0
    dof = total**2 / np.sum(modes**2)
    # the chi-square quantile, 2 P^-1(dof / 2, p) (calib.special: scipy.special costs a command 0.5 s)
    chi2_quantile = 2.0 * gammaincinv(float(dof) / 2.0, probability)
    return float(np.sqrt(total / dof * chi2_quantile))


def robot_covariance(
    cov_free: np.ndarray,
    sensitivity: np.ndarray,
    free: np.ndarray,
    held: np.ndarray,
    held_sigma: np.ndarray,
    robot: np.ndarray,
) -> np.ndarray:
    """The robot's covariance with its held parameters as "consider" parameters (Schmidt): each
    held one may be off by its prior, which moves the TCP itself and the fitted ones by
    ``sensitivity`` per unit (for least squares ``-(A^T A)^-1 A^T J_held``)::

        S = [sensitivity]_robot + E_held,     C = C_free + S diag(held_sigma^2) S^T

    An exact redundancy (joints 2-3's d) cancels in the TCP; a near one does not: on one gauge line
    a few micrometres of unmodelled effect move the weakly determined directions by millimetres.

    Parameters
    ----------
    cov_free : ndarray, shape (n, n)
        The fit's covariance of the free unknowns, internal units.
    sensitivity : ndarray, shape (n, h)
        How far the fit moves each free unknown per unit of each held parameter.
    free : ndarray of int, shape (n,)
        Indices of the free unknowns in the parameter vector.
    held : ndarray of int, shape (h,)
        Indices of the held robot parameters considered.
    held_sigma : ndarray, shape (h,)
        Their prior (1 sigma), internal units.
    robot : ndarray of int, shape (r,), ascending
        Indices of the robot's parameters in the parameter vector (the rest is setup).

    Returns
    -------
    ndarray, shape (r, r)
        Covariance of the robot's error (in the order of ``robot``), internal units.
    """
    free, held, robot = np.asarray(free), np.asarray(held, int), np.asarray(robot)
    in_robot = np.isin(free, robot)
    at_free, at_held = np.searchsorted(robot, free[in_robot]), np.searchsorted(robot, held)
    total = np.zeros((robot.size, held.size))
    total[at_free] = sensitivity[in_robot]
    total[at_held, np.arange(held.size)] += 1.0
    cov = np.zeros((robot.size, robot.size))
    cov[np.ix_(at_free, at_free)] = cov_free[np.ix_(in_robot, in_robot)]
    return cov + (total * held_sigma**2) @ total.T
