"""Is a table still right? Statistics of a table judged on rows it never saw, the robot held and
only the setup unknowns fitted (``calibrate.hold_robot``).

With ``u`` the residuals whitened by what an unchanged robot leaves (the stated noise times the
calibration's own fitted noise scale, at least 1) and ``P`` the projector off the setup's columns,
an unchanged robot gives ``u = P (e + J_r d)``: ``e`` unit noise, ``d`` the table's own error
(covariance ``C`` of the calibration). So ``|u|^2`` is chi-square on ``dof = m - rank(J_s)`` plus
the table's part, ``sum_i l_i chi-square_1`` with ``l_i`` the eigenvalues of ``(P J_r C^1/2)^T (P J_r
C^1/2)``; the test matches that sum by a scaled chi-square (mean and variance, Satterthwaite). A
robot that changed leaves more.

Which parameters moved: each robot column's projection (the setup's part taken out) explains
``(p_k . u)^2 / |p_k|^2`` of the chi-square, with the change ``p_k . u / |p_k|^2`` and its standard
deviation ``1 / |p_k|`` (with the table's own error along ``p_k``, ``|p_k^T P J_r C^1/2| / |p_k|^2``,
added in quadrature: a parameter the table knows only together with a held one moves little
there, whatever its own sigma): the single changes that would
best explain the residual, the parameters a recalibration would most likely move. The same
projection says what the rows would miss: a change ``delta`` of parameter k alone gives an estimate
of mean ``delta`` and that sigma, so it is caught (most times) once ``delta`` is a few sigmas.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import DOWNWEIGHTED_BELOW
from calib.consistency import chi_square_sf


@dataclass(frozen=True)
class DriftTest:
    """The residual of rows the robust loss kept against what an unchanged robot leaves.

    Attributes
    ----------
    noise_ratio : float
        RMS residual per degree of freedom in stated noises (as ``consistency.noise_test``).
    expected_ratio : float
        What an unchanged robot would leave there: the calibration's noise scale and the table's
        uncertainty, in stated noises.
    chi2 : float
        The kept rows' residual in units of what an unchanged robot leaves, scaled so that with
        the table's uncertainty it is about chi-square on ``nu`` (Satterthwaite).
    dof : int
        Kept rows minus the setup unknowns they determine (at least 1).
    p_value : float
        Probability of that chi-square at or above ``chi2``.
    """

    noise_ratio: float
    expected_ratio: float
    chi2: float
    dof: int
    p_value: float

    @property
    def excess(self) -> float:
        """The residual against what an unchanged robot leaves (1: as expected)."""
        return self.noise_ratio / self.expected_ratio


@dataclass(frozen=True)
class Change:
    """One parameter's likely change: column ``index`` of ``x``, the ``change`` and its ``sigma``
    (internal units), the fraction of the chi-square it ``explains`` alone, its ``z`` score."""

    index: int
    change: float
    sigma: float
    explains: float
    z: float


def setup_basis(jac_setup: np.ndarray) -> np.ndarray:
    """An orthonormal basis (m, r) of the setup columns' span (m, s); rank r by singular values."""
    if jac_setup.size == 0:
        return np.zeros((jac_setup.shape[0], 0))
    u, s, _ = np.linalg.svd(jac_setup, full_matrices=False)
    return u[:, s > 1e-10 * s.max()] if s.size and s.max() > 0 else u[:, :0]


def _project(basis: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``a`` (m,) or (m, k) with its part in the basis' span taken out."""
    return a - basis @ (basis.T @ a)


def drift_test(
    residuals: np.ndarray,
    weights: np.ndarray,
    scale: np.ndarray,
    jac_setup: np.ndarray,
    jac_robot: np.ndarray,
    robot_cov: np.ndarray | None,
) -> DriftTest:
    """The drift test of a verification fit.

    Parameters
    ----------
    residuals : ndarray, shape (m,)
        Data residuals at the setup fit, whitened by the stated noise.
    weights : ndarray, shape (m,)
        The robust loss's weights there; a down-weighted row (``DOWNWEIGHTED_BELOW``) stays out.
    scale : ndarray, shape (m,)
        Per row, what an unchanged robot leaves in stated noises (the calibration's noise scale,
        at least 1).
    jac_setup : ndarray, shape (m, s)
        Jacobian of the residuals by the fitted setup unknowns.
    jac_robot : ndarray, shape (m, k)
        Jacobian by the robot's parameters (table, terms) in ``robot_cov``'s order.
    robot_cov : ndarray, shape (k, k), or None
        The calibration's covariance of those parameters (internal units); None: exact.

    Returns
    -------
    DriftTest
    """
    kept = np.asarray(weights, float) ** 2 >= DOWNWEIGHTED_BELOW
    r, s = residuals[kept], scale[kept]
    basis = setup_basis(jac_setup[kept] / s[:, None])
    dof = max(int(kept.sum()) - basis.shape[1], 1)
    u = _project(basis, r / s)
    table = np.zeros(0)
    if robot_cov is not None:
        a = _project(basis, (jac_robot[kept] / s[:, None]) @ _root(robot_cov))
        table = np.clip(np.linalg.eigvalsh(a.T @ a), 0.0, None)
    # |u|^2 = chi-square on dof plus sum_i table_i chi-square_1: matched in mean and variance by
    # c chi-square on nu (Satterthwaite)
    mean, variance = dof + table.sum(), 2.0 * (dof + np.sum(table**2))
    c, nu = variance / (2.0 * mean), 2.0 * mean**2 / variance
    chi2 = float(u @ u) / c
    ratio = float(np.sqrt(np.sum(r**2) / dof))
    expected = float(np.sqrt(np.mean(s**2) * mean / dof))
    return DriftTest(ratio, expected, chi2, dof, chi_square_sf(chi2, nu))


def likely_changes(
    residuals: np.ndarray,
    weights: np.ndarray,
    scale: np.ndarray,
    jac_setup: np.ndarray,
    jac_robot: np.ndarray,
    columns: np.ndarray,
    jac_table: np.ndarray,
    table_cov: np.ndarray | None,
) -> list[Change]:
    """Each robot parameter's change that best explains the residual alone (see the module
    docstring), by how much of the chi-square it explains, largest first.

    Parameters
    ----------
    residuals, weights, scale, jac_setup : ndarray
        As ``drift_test``.
    jac_robot : ndarray, shape (m, k)
        Jacobian by the candidate parameters.
    columns : ndarray of int, shape (k,)
        Their index in ``x`` (``Change.index``).
    jac_table, table_cov : ndarray
        As ``drift_test``'s ``jac_robot`` and ``robot_cov``: the table's own error, whose part along
        each candidate's column adds to its sigma (a parameter the table knows only with another,
        held one moves little there).

    Returns
    -------
    list of Change
    """
    kept, cols, norm2, sigma = _candidates(weights, scale, jac_setup, jac_robot, jac_table, table_cov)
    basis = setup_basis(jac_setup[kept] / scale[kept][:, None])
    u = _project(basis, residuals[kept] / scale[kept])
    total = max(float(u @ u), 1e-300)
    out = []
    for k in np.flatnonzero(np.isfinite(sigma)):
        a = float(cols[:, k] @ u)
        change = -a / norm2[k]  # the step that takes the residual away
        out.append(
            Change(int(columns[k]), change, float(sigma[k]), a * a / norm2[k] / total, abs(change) / sigma[k])
        )
    return sorted(out, key=lambda c: -c.explains)


def caught_changes(
    weights: np.ndarray,
    scale: np.ndarray,
    jac_setup: np.ndarray,
    jac_robot: np.ndarray,
    jac_table: np.ndarray,
    table_cov: np.ndarray | None,
    z_caught: float,
) -> np.ndarray:
    """The smallest change of each robot parameter alone that these rows catch: a change whose
    estimate (``likely_changes``) lies ``z_caught`` of its sigmas out on average, e.g. the test's
    threshold plus 1.28 for nine times in ten.

    Parameters
    ----------
    weights, scale, jac_setup, jac_robot, jac_table, table_cov : ndarray
        As ``likely_changes``.
    z_caught : float
        The change's mean z-score that counts as caught.

    Returns
    -------
    ndarray, shape (k,)
        The change (internal units, >= 0); inf for a parameter these rows do not see.
    """
    return z_caught * _candidates(weights, scale, jac_setup, jac_robot, jac_table, table_cov)[3]


def _candidates(weights, scale, jac_setup, jac_robot, jac_table, table_cov):
    """The kept rows, each candidate's column with the setup's part taken out (m, k), its squared
    norm (k,) and the sigma of its change estimate (k,; inf where the rows do not see it): the
    noise's ``1 / |c_k|`` and the table's own error along the column, ``|c_k^T A C^1/2| / |c_k|^2``."""
    kept = np.asarray(weights, float) ** 2 >= DOWNWEIGHTED_BELOW
    s = scale[kept]
    basis = setup_basis(jac_setup[kept] / s[:, None])
    cols = _project(basis, jac_robot[kept] / s[:, None])
    norm2 = np.sum(cols**2, axis=0)
    seen = norm2 > 1e-12 * max(float(norm2.max(initial=0.0)), 1e-300)
    var = np.full(len(norm2), np.inf)
    var[seen] = 1.0 / norm2[seen]
    if table_cov is not None:
        field = _project(basis, (jac_table[kept] / s[:, None]) @ _root(table_cov))
        var[seen] += np.sum((cols[:, seen].T @ field) ** 2, axis=1) / norm2[seen] ** 2
    return kept, cols, norm2, np.sqrt(var)


def _root(cov: np.ndarray) -> np.ndarray:
    """A square root ``R`` of a covariance (``R R^T = C``), its negative eigenvalues clipped."""
    value, vector = np.linalg.eigh(cov)
    return vector * np.sqrt(np.clip(value, 0.0, None))


def sensitive_rows(
    jac_setup: np.ndarray,
    jac_robot: np.ndarray,
    rows: np.ndarray,
    prior_sigma: np.ndarray,
    n_select: int,
) -> tuple[np.ndarray, float]:
    """A short verification plan: ``n_select`` configurations, greedily, each the one that most
    raises ``log det`` of the robot parameters' information with the setup fitted (its Schur
    complement), a parameter's prior (``prior_sigma``, internal units) regularising what the rows
    do not see yet.

    Parameters
    ----------
    jac_setup : ndarray, shape (m, s)
        Whitened Jacobian of every candidate's residuals by the setup unknowns.
    jac_robot : ndarray, shape (m, k)
        Same, by the parameters the plan should be sensitive to.
    rows : ndarray of int, shape (m,)
        The candidate configuration of each residual.
    prior_sigma : ndarray, shape (k,)
        What is known of each parameter beforehand.
    n_select : int
        How many configurations to choose.

    Returns
    -------
    chosen : ndarray of int
        The chosen configurations, in the order chosen.
    logdet : float
        The log det they reach.
    """
    jac = np.hstack([jac_setup, jac_robot])
    n_s = jac_setup.shape[1]
    ridge = np.concatenate([np.full(n_s, 1e-6), 1.0 / np.asarray(prior_sigma, float) ** 2])
    blocks = {int(c): jac[rows == c] for c in np.unique(rows)}
    info = np.diag(ridge)
    chosen: list[int] = []
    best_value = _schur_logdet(info, n_s)
    for _ in range(min(n_select, len(blocks))):
        best, best_value = -1, -np.inf
        for c, block in blocks.items():
            if c in chosen:
                continue
            trial = info + block.T @ block
            value = _schur_logdet(trial, n_s)
            if value > best_value:
                best, best_value = c, value
        chosen.append(best)
        info = info + blocks[best].T @ blocks[best]
    return np.array(chosen, int), float(best_value)


def _schur_logdet(info: np.ndarray, n_setup: int) -> float:
    """log det of the robot block's information once the first ``n_setup`` unknowns are fitted."""
    a, b, d = info[:n_setup, :n_setup], info[:n_setup, n_setup:], info[n_setup:, n_setup:]
    schur = d - b.T @ np.linalg.solve(a, b) if n_setup else d
    return float(np.linalg.slogdet(schur)[1])
