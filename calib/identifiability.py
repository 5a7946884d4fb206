"""Which parameters the measurements determine: structural gauges and a rank-revealing selection.

Two views that must agree:

- ``structural_holds``: parameters that, by the robot's geometry and the measurement, cannot move
  any residual (or move it exactly like another parameter does);
- ``select_columns``: a rank-revealing, Gram-Schmidt QR of the column-scaled Jacobian in a
  priority order: a column is kept when the part of it that the kept columns cannot produce is
  larger than ``rtol`` of its norm.
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import parallel_axis_pairs

BASE_GAUGE = {
    "J1.theta_deg": "base gauge: a rotation about joint 1's axis is absorbed by the {frame}",
    "J1.d_mm": "base gauge: a shift along joint 1's axis is absorbed by the {frame}",
}


def structural_holds(dh: np.ndarray, tool: np.ndarray, frame: str, tol: float = 1e-6) -> dict[str, str]:
    """Table parameters no position measurement can determine, with the reason, for table ``dh``
    (6, 4) internal units, TCP ``tool`` [mm] in the flange frame, and ``frame`` naming the unknowns
    that absorb the base gauge (e.g. "anchor and the lines")."""
    held = {name: why.format(frame=frame) for name, why in BASE_GAUGE.items()}
    for i in parallel_axis_pairs(dh, tol):
        held[f"J{i + 2}.d_mm"] = (
            f"joints {i + 1} and {i + 2} have parallel axes: J{i + 2}.d shifts along the same axis "
            f"as J{i + 1}.d, only their sum acts"
        )
    theta6, d6, a6, alpha6 = dh[5]
    ca, sa = np.cos(alpha6), np.sin(alpha6)
    x6, y6 = a6 + tool[0], ca * tool[1] - sa * tool[2]  # TCP in frame 5 after Rz(theta6 + q6)
    if np.hypot(x6, y6) < tol:
        held["J6.theta_deg"] = "the TCP lies on joint 6's axis: turning about it does not move the TCP"
    if np.hypot(tool[1], tool[2]) < tol:
        held["J6.alpha_deg"] = "the TCP lies on the flange's x axis: its twist does not move the TCP"
    return held


def select_columns(jac: np.ndarray, order: np.ndarray, rtol: float = 1e-6) -> np.ndarray:
    """Columns of ``jac`` (m, n) that are linearly independent, taken greedily in ``order``.

    A column enters when its component orthogonal to the span of the columns already kept is more
    than ``rtol`` of its norm (zero columns never enter). Returns a boolean mask over the n columns.
    """
    keep = np.zeros(jac.shape[1], bool)
    basis = np.empty((jac.shape[0], 0))
    for k in order:
        col = jac[:, k]
        norm = np.linalg.norm(col)
        if norm == 0.0:
            continue
        rest = col / norm
        for _ in range(2):  # re-orthogonalise once: classical Gram-Schmidt loses orthogonality
            rest = rest - basis @ (basis.T @ rest)
        if np.linalg.norm(rest) > rtol:
            keep[k] = True
            basis = np.column_stack([basis, rest / np.linalg.norm(rest)])
    return keep


def redundancy_partners(jac: np.ndarray, k: int, kept: np.ndarray, names, top: int = 3) -> list[str]:
    """Names of the kept parameters that best reproduce column ``k`` (largest scaled coefficients)."""
    cols = np.flatnonzero(kept)
    scaled = jac[:, cols] / np.maximum(np.linalg.norm(jac[:, cols], axis=0), 1e-300)
    coef = np.linalg.lstsq(scaled, jac[:, k], rcond=None)[0]
    best = np.argsort(-np.abs(coef))[:top]
    return [names[cols[i]] for i in best if abs(coef[i]) > 1e-3 * np.abs(coef).max()]
