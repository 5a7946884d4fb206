"""What a calibration promises away from its samples: parameter covariance pushed to the TCP.

The TCP error field of a table error ``dx`` over configurations is ``J dx`` (``J`` the stacked TCP
Jacobians, (3N, 24)). Re-registering the base absorbs any rigid motion ``t + w x p``, so the part
of ``J`` in that 6-dimensional span is removed first::

    J_perp = (I - B B^+) J,        predicted RMS = sqrt(trace(J_perp C J_perp^T) / N)

with ``B`` (3N, 6) the rigid displacement fields at the nominal TCPs and ``C`` (24, 24) the table's
covariance: the fit's covariance for identified parameters, the manufacturing tolerance squared for
parameters held because the data could not determine them, zero for structural gauges.
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import tcp_jacobian


def rigid_fields(p: np.ndarray) -> np.ndarray:
    """Displacements (3N, 6) of points ``p`` (N, 3) under unit translations and small rotations
    about their centroid."""
    rel = p - p.mean(axis=0)
    fields = np.zeros((p.shape[0], 3, 6))
    fields[:, :, :3] = np.eye(3)
    for k in range(3):
        fields[:, :, 3 + k] = np.cross(np.eye(3)[k], rel)
    return fields.reshape(-1, 6)


def predicted_workspace_rmse(dh: np.ndarray, tool: np.ndarray, q: np.ndarray, cov: np.ndarray) -> float:
    """Predicted RMS TCP error [mm] over configurations ``q`` (N, 6) [rad] for a table covariance
    ``cov`` (24, 24) in internal units, after a rigid re-fit of the base."""
    p, jac = tcp_jacobian(dh, q, tool)
    a = jac.reshape(-1, jac.shape[2])
    q_rigid = np.linalg.qr(rigid_fields(p))[0]
    a_perp = a - q_rigid @ (q_rigid.T @ a)
    return float(np.sqrt(np.einsum("ij,jk,ik->", a_perp, cov, a_perp) / p.shape[0]))


def table_covariance(cov_free: np.ndarray, free: np.ndarray, weak_sigma: dict[int, float]) -> np.ndarray:
    """The (24, 24) table covariance from the fit's covariance over the ``free`` unknowns plus the
    prior variance of table parameters held as weakly determined (``{index: sigma}``)."""
    idx = np.flatnonzero(free)
    table = idx[idx < 24]
    pos = np.searchsorted(idx, table)
    cov = np.zeros((24, 24))
    cov[np.ix_(table, table)] = cov_free[np.ix_(pos, pos)]
    for k, s in weak_sigma.items():
        cov[k, k] = s**2
    return cov
