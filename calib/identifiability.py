"""Which parameters the measurements determine: structural gauges and a rank-revealing selection.

Two views that must agree:

- ``structural_holds``: parameters that, by the robot's geometry and the measurement, cannot move
  any residual (or move it exactly like another parameter does);
- ``select_columns``: a rank-revealing, Gram-Schmidt QR of the column-scaled Jacobian in a
  priority order: a column is kept when the part of it that the kept columns cannot produce is
  larger than ``rtol`` of its norm;
- ``weakly_determined``: of the columns left, those the data pins down no better than the
  robot is made to (``TOLERANCE``: 0.2 deg, 1 mm), from the covariance under the stated noise;
- ``identify``: all three on a model at a point, with each held parameter's reason (the
  pipeline's step 2, ``calib.calibrate``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from calib.kinematics import N_DH, parallel_axis_pairs
from calib.lm import NORMAL_ROWS, row_blocks
from calib.params import display_unit

if TYPE_CHECKING:
    from calib.models import MeasurementModel

TOLERANCE_DEG, TOLERANCE_MM = 0.2, 1.0
"""Manufacturing tolerance of a link parameter (1 sigma): what is known before measuring."""


def tolerance(names) -> np.ndarray:
    """Manufacturing tolerance of table parameters.

    Parameters
    ----------
    names : sequence of str, length k
        Parameter names (``calib.params.DH_NAMES``): ``*_deg`` angles, else lengths.

    Returns
    -------
    ndarray, shape (k,)
        ``TOLERANCE_DEG`` in rad for an angle, ``TOLERANCE_MM`` for a length.
    """
    return np.array([np.radians(TOLERANCE_DEG) if n.endswith("_deg") else TOLERANCE_MM for n in names])


BASE_GAUGE = {
    "J1.theta_deg": "base gauge: a rotation about joint 1's axis is absorbed by the {frame}",
    "J1.d_mm": "base gauge: a shift along joint 1's axis is absorbed by the {frame}",
}


def structural_holds(dh: np.ndarray, tool: np.ndarray, frame: str, tol: float = 1e-6) -> dict[str, str]:
    """Table parameters no position measurement can determine, with the reason.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units.
    tool : ndarray, shape (3,)
        TCP in the flange frame [mm].
    frame : str
        The unknowns that absorb the base gauge, for the reason (e.g. "anchor and the lines").
    tol : float
        How close to parallel / on-axis counts as exactly so (rad, mm).

    Returns
    -------
    dict of str to str
        Parameter name (``DH_NAMES``) to why it is held.
    """
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
    """Columns that are linearly independent, taken greedily in a priority order.

    A column enters when its component orthogonal to the span of the columns already kept is more
    than ``rtol`` of its norm. Columns below 1e-9 of the largest norm are zero up to round-off and
    never enter.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Jacobian (any column scaling: each column is normalised).
    order : ndarray of int, shape (k,)
        The candidate columns, first priority first.
    rtol : float
        Relative size of the new part below which a column counts as produced by the others.

    Returns
    -------
    ndarray of bool, shape (n,)
        The columns kept.
    """
    keep = np.zeros(jac.shape[1], bool)
    space = np.empty((jac.shape[0], len(order)))  # the kept columns' orthonormal basis, filled in turn
    size = 0
    norms = np.linalg.norm(jac, axis=0)
    for k in order:
        col, norm = jac[:, k], norms[k]
        if norm <= 1e-9 * norms.max():
            continue
        rest, basis = col / norm, space[:, :size]
        for _ in range(2):  # re-orthogonalise once: classical Gram-Schmidt loses orthogonality
            rest = rest - basis @ (basis.T @ rest)
        if np.linalg.norm(rest) > rtol:
            keep[k] = True
            space[:, size] = rest / np.linalg.norm(rest)
            size += 1
    return keep


def redundancy_partners(jac: np.ndarray, k: int, kept: np.ndarray, names, top: int = 3) -> list[str]:
    """The kept parameters that best reproduce a column, for a message.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Jacobian.
    k : int
        The column to explain.
    kept : ndarray of bool, shape (n,)
        Columns that may explain it (``select_columns``).
    names : sequence of str, length n
        Parameter names.
    top : int
        Most names returned.

    Returns
    -------
    list of str
        Names by decreasing coefficient of ``k``'s least-squares reproduction from the normalised
        kept columns (coefficients below 1e-3 of the largest left out).
    """
    cols = np.flatnonzero(kept)
    scaled = jac[:, cols] / np.maximum(np.linalg.norm(jac[:, cols], axis=0), 1e-300)
    coef = np.linalg.solve(scaled.T @ scaled, scaled.T @ jac[:, k])
    best = np.argsort(-np.abs(coef))[:top]
    return [names[cols[i]] for i in best if abs(coef[i]) > 1e-3 * np.abs(coef).max()]


def weakly_determined(jac: np.ndarray, cols: np.ndarray, candidates, tol: np.ndarray) -> dict[int, float]:
    """Candidates whose standard deviation exceeds their tolerance (what is known before
    measuring), found one at a time (worst ratio first) since holding one sharpens the others.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Whitened Jacobian (unit noise).
    cols : sequence of int
        Every column in the fit.
    candidates : set of int
        The columns that may be held.
    tol : ndarray, shape (n,)
        Tolerances, internal units (only the candidates' entries are read).

    Returns
    -------
    dict of int to float
        Held column to its standard deviation in the fit it was dropped from, internal units.
    """
    cols, held = list(cols), {}
    while True:
        j = jac[:, cols]
        cov = np.linalg.pinv(j.T @ j)
        sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
        ratios = {c: sigma[i] / tol[c] for i, c in enumerate(cols) if c in candidates}
        if not ratios:
            return held
        worst = max(ratios, key=ratios.get)
        if ratios[worst] <= 1.0:
            return held
        held[worst] = float(sigma[cols.index(worst)])
        cols.remove(worst)


def identify(
    model: MeasurementModel,
    x: np.ndarray,
    free_setup: np.ndarray,
    gauges: dict[str, str],
    rtol: float,
    hold_weak: bool = True,
) -> tuple[np.ndarray, dict[str, str]]:
    """The robot parameters (table and terms) the data determines at ``x``, and why the others are
    held.

    Structural ``gauges`` are held first; a rank-revealing selection over the column-scaled
    Jacobian (setup unknowns first, then the table joint by joint, then the terms) holds what the
    data cannot tell apart; then a parameter is held where the data pins it down no better than
    what is known before measuring (``model.prior_sigma()``: a table parameter's manufacturing
    tolerance, a term's prior).

    Parameters
    ----------
    model : MeasurementModel
        The data's model.
    x : ndarray, shape (n,)
        Where to linearise (the setup fit), internal units.
    free_setup : ndarray of bool, shape (n,)
        Setup unknowns that are fitted.
    gauges : dict of str to str
        Parameters held by structure, with reasons.
    rtol : float
        Relative column size below which a scaled column counts as produced by the others.
    hold_weak : bool
        Whether to hold what the data determines no better than its prior (else it is estimated,
        its prior keeping it near where the robot was built).

    Returns
    -------
    robot : ndarray of bool, shape (n,)
        The identified robot parameters.
    held : dict of str to str
        Every held parameter of ``model.names`` and why.
    """
    jac = column_geometry(model.residuals_and_jacobian(x)[1])
    names = model.names
    candidates = [k for k in np.flatnonzero(~model.setup_mask) if names[k] not in gauges]
    order = np.concatenate([np.flatnonzero(free_setup), candidates]).astype(int)
    kept = select_columns(jac, order, rtol)
    held = {n: r for n, r in gauges.items() if n in names}
    norms = np.linalg.norm(jac, axis=0)
    for k in candidates:
        if kept[k]:
            continue
        if norms[k] <= 1e-9 * norms.max():
            held[names[k]] = "it moves none of the measured points"
        else:
            partners = ", ".join(redundancy_partners(jac, k, kept, names))
            held[names[k]] = f"the data cannot tell it apart from {partners}"
    kept_robot = [k for k in candidates if kept[k]]
    prior = model.prior_sigma()
    weak = {}
    if hold_weak:
        weak = weakly_determined(jac, np.flatnonzero(free_setup | kept), set(kept_robot), prior)
    for k, sigma in weak.items():
        held[names[k]] = weak_reason(
            names[k], sigma, prior[k], "manufacturing tolerance" if k < N_DH else "prior"
        )
    robot = np.zeros(len(names), bool)
    robot[[k for k in kept_robot if k not in weak]] = True
    return robot, held


def column_geometry(jac: np.ndarray) -> np.ndarray:
    """``jac`` (m, n) itself on rows that fit one block (``NORMAL_ROWS``: planning's, as before);
    on more, ``R`` (n, n) of its QR factorisation, built block by block: the same column norms and
    angles (``R^T R = J^T J``, all ``identify`` looks at) in n rows instead of m."""
    if len(jac) <= NORMAL_ROWS:
        return jac
    r = np.empty((0, jac.shape[1]))
    for block in row_blocks(jac):
        r = np.linalg.qr(np.vstack([r, block]), mode="r")
    return r


def weak_reason(name: str, sigma: float, prior: float, what: str) -> str:
    """Why a parameter is held although the data sees it: its ``sigma`` from the data against its
    ``prior`` (both internal units), ``what`` the prior is (a tolerance, a prior)."""
    factor, unit = display_unit(name)
    return (
        f"the data determines it only to +-{sigma * factor:.3g} {unit}, no better than its "
        f"{what} (+-{prior * factor:.3g} {unit})"
    )
