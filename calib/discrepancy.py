"""The model's discrepancy: what the robot's model cannot express, correlated in joint space.

A real arm's error is not the table, the terms and white noise alone. What is left (a gear's
cyclic error, a cable's pull, a bearing's play) changes smoothly with the joints, so poses a few
degrees apart share it. A least-squares fit that counts every row as independent is then steered
by wherever the rows crowd: a session confined to one region of joint space (one elbow
configuration, a narrow band of joint 2) has its table and compliances absorb that region's
error in directions it cannot separate, and they extrapolate wrongly to poses it never visited
(the real UR10, ``benchmarks/IPA_UR10.md``).

So every residual group of the sample rows gets, beside its noise, a joint-space error with the
squared-exponential covariance ``ratio * exp(-d^2 / (2 l^2))`` (in units of the group's noise
variance; ``d`` the chord distance of joints 1-3, which carry the arm; each component of a row,
e.g. x, y, z of a tracker point, its own), and the table is fitted by generalised least squares
under it: the fit weighs what the poses share once, not once per pose. The length scale ``l`` and
``ratio`` are those of greatest restricted likelihood (REML: the likelihood of the residuals with
the fitted unknowns integrated out) over ``LENGTH_SCALES_DEG`` x ``RATIOS`` at the white fit
(coordinate ascent over that grid), and
used only where they beat no discrepancy beyond chance (``MIN_GAIN``): a simulated cell, whose
error is the table and white noise, keeps its white fit.

Beyond ``BLOCK_ROWS`` rows a group's covariance is block-diagonal over regions of joint space
(``calib.kmeans.region_folds``), so the cost grows with the rows, not their cube.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kmeans import REGION_JOINTS, region_folds

LENGTH_SCALES_DEG = (2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 25.0)
"""Correlation lengths tried [deg of joints 1-3]."""
RATIOS = (1.0, 3.0, 10.0, 30.0, 100.0, 300.0)
"""Discrepancy variances tried, in units of each group's noise variance."""
MIN_GAIN = float(np.log(len(LENGTH_SCALES_DEG) * len(RATIOS) / 0.0027))
"""Restricted log-likelihood gain over no discrepancy the best grid point must bring: a likelihood
ratio test at p 0.0027 (three sigma, two hyperparameters: chi-square with 2 degrees of freedom),
Bonferroni'd over the grid."""
BLOCK_ROWS = 1500
"""Rows of a group beyond which its covariance is split into regions of joint space."""


@dataclass(frozen=True)
class Discrepancy:
    """The joint-space error a calibration was weighted by.

    Attributes
    ----------
    length_scale_deg : float
        Its correlation length over joints 1-3 [deg].
    ratio : float
        Its variance over each group's noise variance.
    loglik_gain : float
        The restricted log-likelihood it gains over no discrepancy.
    tcp_rms_mm : float
        The RMS error [mm] it puts on the TCP at a pose, which no table takes out
        (``tcp_rms_mm``; 0 until the weighted fit sets it).
    """

    length_scale_deg: float
    ratio: float
    loglik_gain: float
    tcp_rms_mm: float = 0.0


def joint_distance2(q: np.ndarray) -> np.ndarray:
    """Squared distance (N, N) [rad^2] between the poses ``q`` (N, 6) [rad] over joints 1-3: the
    chord (``2 sin(dq / 2)`` per joint), so a full turn is no distance."""
    z = q[:, :REGION_JOINTS]
    return np.sum((2.0 * np.sin((z[:, None, :] - z[None, :, :]) / 2.0)) ** 2, axis=2)


def correlation(distance2: np.ndarray, length_scale_rad: float) -> np.ndarray:
    """The squared-exponential correlation ``exp(-d^2 / (2 l^2))`` of squared distances [rad^2]."""
    return np.exp(-distance2 / (2.0 * length_scale_rad**2))


def joint_kernel(q: np.ndarray, length_scale_rad: float) -> np.ndarray:
    """Correlation (N, N) of the poses ``q`` (N, 6) [rad] (``joint_distance2``, ``correlation``)."""
    return correlation(joint_distance2(q), length_scale_rad)


class Blocks:
    """The residual elements a discrepancy correlates: per residual group of ``pose_groups``, its
    elements as a (rows, components) table split into regions of joint space.

    Parameters
    ----------
    rows, groups : ndarray of int, shape (m,)
        Each residual element's sample row (-1 for a prior row) and group.
    pose_groups : tuple of int
        The groups to correlate (``MeasurementModel.pose_groups``); the others stay white.
    q : ndarray, shape (N, 6)
        The samples' joint readings [rad].
    weights : ndarray, shape (m,)
        The fit's robust weights; a row's noise is scaled by the least of its components'.
    """

    def __init__(self, rows: np.ndarray, groups: np.ndarray, pose_groups, q: np.ndarray, weights: np.ndarray):
        self.tables, self.distance2, self.noise = [], [], []
        self.white = np.ones(rows.size, bool)
        for g in pose_groups:
            elements = np.flatnonzero((groups == g) & (rows >= 0))
            elements = elements[np.argsort(rows[elements], kind="stable")]
            sample_rows, counts = np.unique(rows[elements], return_counts=True)
            if counts.min() != counts.max():
                continue  # rows with a varying number of components: left white
            table = elements.reshape(sample_rows.size, counts[0])
            row_weight = np.min(weights[table], axis=1)
            k = -(-sample_rows.size // BLOCK_ROWS)
            for part in region_folds(q[sample_rows], k) if k > 1 else [np.arange(sample_rows.size)]:
                self.tables.append(table[part])
                self.distance2.append(joint_distance2(q[sample_rows[part]]))
                self.noise.append(1.0 / np.maximum(row_weight[part], 1e-12) ** 2)
            self.white[elements] = False

    def factors(self, discrepancy: Discrepancy | None) -> list[np.ndarray]:
        """Lower Cholesky factor of each block's covariance, noise plus ``discrepancy``."""
        out = []
        for distance2, noise in zip(self.distance2, self.noise, strict=True):
            cov = np.diag(noise)
            if discrepancy is not None:
                cov += discrepancy.ratio * correlation(distance2, np.radians(discrepancy.length_scale_deg))
            out.append(np.linalg.cholesky(cov))
        return out

    def whiten(
        self, factors: list[np.ndarray], weights: np.ndarray, r: np.ndarray, jac: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals (m,) and Jacobian (m, n) with each block's covariance whitened out and the
        other elements weighted by ``weights``."""
        from scipy.linalg import solve_triangular  # only here: a gauge-line session never needs scipy

        r_out = r * np.where(self.white, weights, 1.0)
        j_out = None if jac is None else jac * np.where(self.white, weights, 1.0)[:, None]
        for table, lower in zip(self.tables, factors, strict=True):
            n, c = table.shape
            block = r[table] if jac is None else np.hstack([r[table], jac[table].reshape(n, -1)])
            whitened = solve_triangular(lower, block, lower=True, check_finite=False)
            r_out[table] = whitened[:, :c]
            if jac is not None:
                j_out[table] = whitened[:, c:].reshape(n, c, jac.shape[1])
        return r_out, j_out

    def log_det(self, factors: list[np.ndarray]) -> float:
        """Log-determinant of the whole covariance the factors make (white elements count 1)."""
        pairs = zip(self.tables, factors, strict=True)
        return float(sum(2.0 * t.shape[1] * np.sum(np.log(np.diag(f))) for t, f in pairs))


class Correlated:
    """A prior-augmented model (``calib.calibrate.WithPrior``) whose elements in ``blocks`` are
    whitened by noise plus ``discrepancy`` and the others weighted by the robust ``weights`` of the
    fit it starts from: its least squares is the generalised least squares under that covariance."""

    def __init__(self, prior, blocks: Blocks, discrepancy: Discrepancy, weights: np.ndarray):
        self.prior, self.model, self.blocks = prior, prior.model, blocks
        self.names, self.x0, self.groups, self.rows = prior.names, prior.x0, prior.groups, prior.rows
        self.setup_mask, self.tool_mask = prior.setup_mask, prior.tool_mask
        self.weights = np.asarray(weights, float)
        self.factors = blocks.factors(discrepancy)

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True):
        """Whitened residuals (m,) and Jacobian (m, n) at ``x`` (n,)."""
        r, jac = self.prior.residuals_and_jacobian(x, jacobian)
        return self.blocks.whiten(self.factors, self.weights, r, jac)


def estimate(
    residuals: np.ndarray,
    jacobian: np.ndarray,
    noise: np.ndarray,
    blocks: Blocks,
    weights: np.ndarray,
) -> Discrepancy | None:
    """The grid's discrepancy of greatest restricted likelihood (found by coordinate ascent, below),
    None unless it beats none by ``MIN_GAIN``.

    Parameters
    ----------
    residuals : ndarray, shape (m,)
        The white fit's residuals (stated-noise units, prior rows included).
    jacobian : ndarray, shape (m, k)
        Their Jacobian by the fitted unknowns.
    noise : ndarray, shape (m,)
        Each element's fitted noise in stated units (its group's scale; 1 for prior rows), so every
        group's noise is one before the discrepancy is added.
    blocks : Blocks
        The correlated elements (built with ``weights``).
    weights : ndarray, shape (m,)
        The white fit's robust weights.
    """
    r, jac = residuals / noise, jacobian / noise[:, None]
    m, k = jac.shape

    def restricted(discrepancy):
        factors = blocks.factors(discrepancy)
        rw, jw = blocks.whiten(factors, weights, r, jac)
        d = np.linalg.norm(jw, axis=0)
        d[d == 0] = 1.0
        # R of [J | r]: its first k diagonals give log det(J^T J), its last the residual's norm
        diag = np.abs(np.diag(np.linalg.qr(np.column_stack([jw / d, rw]), mode="r")))
        log_info = 2.0 * np.sum(np.log(np.maximum(diag[:k], 1e-300) * d))
        return -0.5 * ((m - k) * np.log(diag[k] ** 2 / (m - k)) + blocks.log_det(factors) + log_info)

    white = restricted(None)
    gains = {}

    def gain(length, ratio):
        if (length, ratio) not in gains:
            gains[length, ratio] = restricted(Discrepancy(length, ratio, 0.0)) - white
        return gains[length, ratio]

    # coordinate ascent over the grid: the length at a middling ratio, the ratio at that length,
    # then the length again at that ratio (18 of the 42 points; the surface is smooth in both)
    length = max(LENGTH_SCALES_DEG, key=lambda v: gain(v, RATIOS[2]))
    ratio = max(RATIOS, key=lambda v: gain(length, v))
    length = max(LENGTH_SCALES_DEG, key=lambda v: gain(v, ratio))
    if gains[length, ratio] <= MIN_GAIN:
        return None
    return Discrepancy(length, ratio, float(gains[length, ratio]))


def tcp_rms_mm(discrepancy: Discrepancy, row_error_mm: np.ndarray, components: int) -> float:
    """The RMS TCP error [mm] of ``discrepancy`` at a pose: its share ``ratio / (1 + ratio)`` of the
    rows' mean squared error ``row_error_mm`` (N,) [mm] after the fit, each row seeing
    ``components`` of the TCP's three (a tracker point 3, a drawstring's distance 1)."""
    share = discrepancy.ratio / (1.0 + discrepancy.ratio)
    return float(np.sqrt(3.0 / components * share * np.mean(row_error_mm**2)))
