"""Joint angle errors: each of joints 1-3 turning by a smooth function of its own angle more than it
reads (a gear's or strain wave's cyclic error, many cycles a turn: on the real UR10 joints 2 and 3
some 17 times a turn), seen at the TCP through the arm's Jacobian.

Each joint's error is a Gaussian process over its angle, written in harmonics ``1..HARMONICS``::

    dq_j(q_j) = sum_k a_jk cos(k q_j) + b_jk sin(k q_j),   a_jk, b_jk ~ N(0, sigma^2 rho_k),
    rho_k ∝ exp(-(k l)^2 / 2),  sum_k rho_k = 1,

a wrapped Gaussian kernel of length ``l`` [rad] and size ``sigma`` [rad] (the order 0 is the
table's offset). The TCP moves by ``sum_j J_j(q) dq_j(q_j)``, ``J_j`` the derivative of the TCP by
joint j's angle, so the coefficients are a Bayesian linear regression of the rows' residual vectors
(each row's residual counted white with the rows' mean square per component). Unlike a kernel over
all three joints at once, a joint's function is learnt wherever that joint stood, whatever the
others did; at angles no row visited it falls back to zero within a few ``l``.

``l`` and ``sigma`` are those of least cross-validated error on ``FOLDS`` interleaved folds
(coordinate descent over ``LENGTHS_DEG`` x ``SIGMAS_DEG``); the errors are used only where they cut
the table's fold error by ``MIN_GAIN`` and by more than the held-out rows' own scatter could by
chance (``clear_gain``; ``fit_angle_errors`` returns None).

A gear's error concentrates on one order (its tooth mesh: the UR10's 17 cycles a turn), which the
kernel spreads over its neighbours; where rows see each joint's error through one projection only
(a drawstring cell's), that spread leaves the error partly unseen in 3-D. ``sharpened`` then picks,
joint by joint on the same folds, the kernel, the kernel with ``LINE_SHARES`` of its prior moved to
the joint's strongest order, or the joint quiet (``QUIET``); the drawstring map uses it
(``calib.absorbed_angles``), a tracker's rows, which see the error whole, keep the kernel (IPA UR10,
train B test A, C, D: 0.375 -> 0.389 mm with it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.blocks import each_block, halved
from calib.kinematics import THETA, tcp_jacobian

ANGLE_JOINTS = 3
"""Joints 1-3 carry an angle error."""
HARMONICS = 60
"""Highest order [cycles per turn] of a joint's angle error."""
FEATURE_ROWS = 1024
"""Rows per block of ``features``: a block's responses (1,024 x 3 x 360) stay 9 MB."""
LENGTHS_DEG = (3.0, 4.0, 6.0, 10.0)
"""Kernel lengths tried [deg]: from 3 deg, where the 60th harmonic's weight is 0.7 % of the first's,
so the truncated kernel still falls off as a Gaussian (to -2 %, the zero mean over a turn, beyond
three lengths) and a joint's error falls back away from the angles visited."""
SIGMAS_DEG = (0.005, 0.01, 0.02, 0.05)
"""Sizes of a joint's angle error tried [deg RMS]."""
FOLDS = 5
"""Interleaved cross-validation folds (row ``i`` in fold ``i mod FOLDS``)."""
MIN_GAIN = 0.05
"""Cut of the cross-validated RMS error against the table alone the errors must bring."""
LINE_SHARES = (0.9, 0.99, 0.999)
"""Shares of a joint's prior variance put on its strongest order tried (``sharpened``)."""
QUIET = 1e-3
"""Factor on the prior variance of a joint ``sharpened`` finds without an error (not zero: the
posterior takes the prior's inverse)."""
GAIN_SIGMAS = 2.0
"""Standard errors of the held-out rows' mean gain in squared error (``clear_gain``) a fit's gain
must clear besides ``MIN_GAIN``: with few rows a 5 % cut comes by chance (a clean simulated 36-row
session's map came on in 2 draws of 40, from the angle errors and from the shared error, a
gain within 1 standard error each)."""


def clear_gain(gain: np.ndarray, row: np.ndarray) -> bool:
    """Is the mean over rows of the held-out ``gain`` (K,) (each observation's squared error with the
    table alone minus with the fit, summed over each row's observations by ``row`` (K,)) more than
    ``GAIN_SIGMAS`` of its standard errors above zero?"""
    per_row = np.bincount(np.unique(row, return_inverse=True)[1], gain)
    if per_row.size < 2:
        return False
    return bool(np.mean(per_row) > GAIN_SIGMAS * np.std(per_row, ddof=1) / np.sqrt(per_row.size))


def joint_jacobian(dh: np.ndarray, q: np.ndarray, tool_mm: np.ndarray) -> np.ndarray:
    """Derivatives (N, 3, ANGLE_JOINTS) [mm/rad] of the TCP (base frame) by the angles of joints
    1-3, table ``dh`` (6, 4) (rad, mm), readings ``q`` (N, 6) [rad], TCP ``tool_mm`` (3,) [mm]."""
    _, jac = tcp_jacobian(dh, q, tool_mm)
    return jac[:, :, [4 * j + THETA for j in range(ANGLE_JOINTS)]]


def features(q: np.ndarray, jacobian: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """The TCP's response (M, 3, F) [mm/rad] to each coefficient (F = ANGLE_JOINTS x 2 HARMONICS:
    per joint the cosines, then the sines) at readings ``q`` (N, 6) [rad] with ``jacobian``
    (M, 3, ANGLE_JOINTS), row i of it at the readings ``q[rows[i]]`` (default: M = N, the same
    rows; several residuals of a row share its harmonics, computed once), written a block of rows
    at a time (``calib.blocks``)."""
    angle = q[:, :ANGLE_JOINTS, None] * np.arange(1, HARMONICS + 1)
    basis = np.concatenate([np.cos(angle), np.sin(angle)], axis=2)  # (N, ANGLE_JOINTS, 2 HARMONICS)
    out = np.empty(jacobian.shape[:2] + (ANGLE_JOINTS, 2 * HARMONICS))

    def block(s: int, e: int) -> None:
        at = basis[s:e] if rows is None else basis[rows[s:e]]
        np.multiply(jacobian[s:e, :, :, None], at[:, None], out=out[s:e])

    each_block(len(out), FEATURE_ROWS, block)
    return out.reshape(out.shape[0], out.shape[1], -1)


def prior_variance(length_deg: float, sigma_deg: float) -> np.ndarray:
    """Prior variance (F,) [rad^2] of each coefficient (``features``' order)."""
    order = np.arange(1, HARMONICS + 1)
    rho = np.exp(-((order * np.radians(length_deg)) ** 2) / 2.0)
    rho /= rho.sum()
    return np.tile(np.concatenate([rho, rho]), ANGLE_JOINTS) * np.radians(sigma_deg) ** 2


@dataclass(frozen=True)
class AngleErrors:
    """Fitted angle errors of joints 1-3.

    Attributes
    ----------
    length_deg, sigma_deg : float
        The kernel's length [deg] and size [deg RMS].
    weights : ndarray, shape (F,)
        The coefficients' posterior mean [rad].
    covariance : ndarray, shape (F, F)
        Their posterior covariance [rad^2].
    rest_mm2 : float
        Mean square per component [mm^2] of what they leave on the folds.
    """

    length_deg: float
    sigma_deg: float
    weights: np.ndarray
    covariance: np.ndarray
    rest_mm2: float

    def mean(self, q: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
        """The TCP error (M, 3) [mm, base frame] at readings ``q`` (M, 6) [rad] with ``jacobian``
        (M, 3, ANGLE_JOINTS)."""
        return features(q, jacobian) @ self.weights

    def predict(self, q: np.ndarray, jacobian: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The TCP error (M, 3) [mm, base frame] at readings ``q`` (M, 6) [rad] with ``jacobian``
        (M, 3, ANGLE_JOINTS), and its posterior variance per component (M,) [mm^2]."""
        return self.of_features(features(q, jacobian))

    def of_features(self, a: np.ndarray, widest: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The TCP error (M, 3) [mm] and its variance per component (M,) [mm^2] of the TCP's
        responses ``a`` (M, 3, F) [mm/rad] to the coefficients: the mean of the three components',
        or with ``widest`` the variance along the direction of the largest (a bound that holds where
        the uncertainty lies along one direction, as where rows see the error along few)."""
        if not widest:
            return a @ self.weights, np.sum((a @ self.covariance) * a, axis=(1, 2)) / 3.0
        return a @ self.weights, np.linalg.eigvalsh((a @ self.covariance) @ a.transpose(0, 2, 1))[:, -1]


def posterior_mean(gram: np.ndarray, moment: np.ndarray, noise: float, prior: np.ndarray) -> np.ndarray:
    """Posterior mean (F,) [rad] of the coefficients from ``gram`` = A^T A, ``moment`` = A^T e, white
    ``noise`` [mm^2] per component and ``prior`` (F,) [rad^2] (numpy's LU solve: scipy.linalg's
    Cholesky would cost every default ``station calibrate`` 0.2 s of import, issue 26)."""
    a = gram / noise
    a[np.diag_indices_from(a)] += 1.0 / prior  # the prior's precision on the diagonal, no (F, F) copy
    return np.linalg.solve(a, moment / noise)


def posterior_means(grams: np.ndarray, moments: np.ndarray, noise: float, prior: np.ndarray) -> np.ndarray:
    """``posterior_mean`` (G, F) of each of a stack of ``grams`` (G, F, F) and ``moments`` (G, F)
    (the folds' training sets), the same numbers, a stack of systems a thread: numpy's batched solve
    lets the other thread run, its solve of one system does not (measured: five 360 x 360 systems
    4.0 ms one at a time, 2.6 ms in two stacks)."""
    out = np.empty(moments.shape)

    def block(s: int, e: int) -> None:
        a = grams[s:e] / noise
        a.reshape(len(a), -1)[:, :: a.shape[-1] + 1] += 1.0 / prior
        out[s:e] = np.linalg.solve(a, moments[s:e, :, None] / noise)[..., 0]

    each_block(len(out), halved(len(out), len(out), least=1), block)
    return out


def posterior_covariance(gram: np.ndarray, noise: float, prior: np.ndarray) -> np.ndarray:
    """Posterior covariance (F, F) [rad^2] of the coefficients (see ``posterior_mean``)."""
    return np.linalg.inv(gram / noise + np.diag(1.0 / prior))


DESIGN_ROWS = 8192
"""Observations per block of the design: a block's responses (DESIGN_ROWS x F) stay some 20 MB, not
a million rows' 9 GB."""


def design_rows(design: np.ndarray):
    """``design_blocks`` of a design (K, F) held whole: (slice of observations, its rows)."""
    for s in range(0, len(design), DESIGN_ROWS):
        yield slice(s, s + DESIGN_ROWS), design[s : s + DESIGN_ROWS]


class Folds:
    """Per interleaved fold, the Gram matrix and moment of its observations, and the sum of their
    squares and their count: what predicting its observations from the other folds needs.

    Parameters
    ----------
    design_blocks : callable
        ``design_blocks()`` yields (slice of the observations, their responses (k, F) [mm/rad] to the
        coefficients: ``features`` seen along each observation's direction), the K observations in
        order (``design_rows`` of a whole design).
    value_mm : ndarray, shape (K,)
        The observed residuals [mm].
    row : ndarray, shape (K,)
        The row of each observation (row ``i`` in fold ``i mod FOLDS``).
    """

    def __init__(self, design_blocks, value_mm: np.ndarray, row: np.ndarray):
        self.design_blocks, self.value, self.row = design_blocks, value_mm, row
        self.fold = fold = row % FOLDS
        self.noise = float(np.mean(value_mm**2))
        self.grams, self.moments, self.squares = [0.0] * FOLDS, [0.0] * FOLDS, [0.0] * FOLDS
        for at, a_block in design_blocks():
            e_block, f_block = value_mm[at], fold[at]
            for f in range(FOLDS):
                a, e = a_block[f_block == f], e_block[f_block == f]
                self.grams[f] = self.grams[f] + a.T @ a
                self.moments[f] = self.moments[f] + a.T @ e
                self.squares[f] += float(e @ e)
        self.count = value_mm.size
        self.gram, self.moment = sum(self.grams), sum(self.moments)
        self.trained = self.gram - np.stack(self.grams), self.moment - np.stack(self.moments)
        """Each fold's training set's Gram matrix and moment (the other folds'), stacked."""
        self.table_error = float(np.sqrt(3.0 * self.noise))
        """The table alone's fold error [mm] (three components of the mean square)."""

    def error(self, length_deg: float, sigma_deg: float) -> float:
        """3-D RMS error [mm] (three components of the mean square) of every observation predicted
        from the other folds: per fold ``|e - A w|^2 = e.e - 2 w.A^T e + w.A^T A w``."""
        return self.error_of(prior_variance(length_deg, sigma_deg))

    def error_of(self, prior: np.ndarray) -> float:
        """``error`` of the coefficients' ``prior`` (F,) [rad^2] variance."""
        squares = 0.0
        weights = posterior_means(*self.trained, self.noise, prior)
        for w, g, m, ee in zip(weights, self.grams, self.moments, self.squares, strict=True):
            squares += ee - 2.0 * w @ m + w @ g @ w
        return float(np.sqrt(3.0 * max(squares, 0.0) / self.count))

    def gains(self, length_deg: float, sigma_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """Each observation's squared error [mm^2] predicted from the other folds with the table
        alone minus with the errors (K,), and its row (K,) (``clear_gain``): one more pass over
        the design."""
        weights = posterior_means(*self.trained, self.noise, prior_variance(length_deg, sigma_deg))
        predicted = np.empty_like(self.value)
        for at, a_block in self.design_blocks():
            out, f_block = predicted[at], self.fold[at]
            for f in range(FOLDS):
                out[f_block == f] = a_block[f_block == f] @ weights[f]
        return self.value**2 - (self.value - predicted) ** 2, self.row


def search(folds) -> dict[tuple[float, float], float]:
    """Fold error [mm] per (length, size) visited: the length at the middling size, the size at that
    length, the length again."""
    scores = {}

    def score(length, sigma):
        if (length, sigma) not in scores:
            scores[length, sigma] = folds.error(length, sigma)
        return scores[length, sigma]

    length = min(LENGTHS_DEG, key=lambda v: score(v, SIGMAS_DEG[2]))
    sigma = min(SIGMAS_DEG, key=lambda v: score(length, v))
    min(LENGTHS_DEG, key=lambda v: score(v, sigma))
    return scores


def strongest_order(weights: np.ndarray, prior: np.ndarray, joint: int) -> int:
    """Index (0-based) of joint ``joint``'s order whose coefficients ``weights`` (F,) [rad] stand
    highest against their ``prior`` (F,) [rad^2] variance (their power over it)."""
    at = slice(2 * HARMONICS * joint, 2 * HARMONICS * (joint + 1))
    w, p = weights[at], prior[at]
    return int(np.argmax((w[:HARMONICS] ** 2 + w[HARMONICS:] ** 2) / p[:HARMONICS]))


def joint_priors(prior: np.ndarray, weights: np.ndarray, sigma_deg: float, joint: int) -> list[np.ndarray]:
    """The priors (F,) [rad^2] ``sharpened`` tries for joint ``joint``: ``prior`` with
    ``LINE_SHARES`` of the joint's variance moved to its ``strongest_order`` (the joint's size
    ``sigma_deg`` kept), then the joint ``QUIET``."""
    at = slice(2 * HARMONICS * joint, 2 * HARMONICS * (joint + 1))
    order = 2 * HARMONICS * joint + strongest_order(weights, prior, joint) + np.array([0, HARMONICS])
    out = []
    for share in LINE_SHARES:
        p = prior.copy()
        p[at] *= 1.0 - share
        p[order] += share * np.radians(sigma_deg) ** 2
        out.append(p)
    quiet = prior.copy()
    quiet[at] *= QUIET
    return out + [quiet]


def sharpened(folds, angles: AngleErrors) -> tuple[np.ndarray, float]:
    """The prior (F,) [rad^2] of least fold error (``folds.error_of``) from the kernel of ``angles``,
    a joint at a time (forward selection: first the joint whose best of ``joint_priors``, a line at
    its strongest order in ``angles.weights`` or quiet, cuts the folds' error most, kept where it
    cuts it), and its fold error (``folds``' units)."""
    prior = prior_variance(angles.length_deg, angles.sigma_deg)
    best, left = folds.error_of(prior), list(range(ANGLE_JOINTS))
    while left:
        tried = []
        for joint in left:
            priors = joint_priors(prior, angles.weights, angles.sigma_deg, joint)
            tried += [(folds.error_of(p), joint, p) for p in priors]
        error, joint, p = min(tried, key=lambda t: t[0])
        left.remove(joint)
        if error < best:
            best, prior = error, p
    return prior, best


def fit_angle_errors(q: np.ndarray, jacobian: np.ndarray, error_mm: np.ndarray) -> AngleErrors | None:
    """Angle errors of joints 1-3 from rows ``q`` (N, 6) [rad], ``jacobian`` (N, 3, ANGLE_JOINTS)
    [mm/rad] and residual vectors ``error_mm`` (N, 3) [mm, base frame] (a tracker's rows: each
    observes its whole error); None unless they cut the table's fold error by ``MIN_GAIN``."""
    if q.shape[0] < 2 * FOLDS:
        return None
    design = features(q, jacobian).reshape(-1, ANGLE_JOINTS * 2 * HARMONICS)
    return fit_observed_angle_errors(design, error_mm.ravel(), np.repeat(np.arange(q.shape[0]), 3))


def observed_features(q: np.ndarray, jacobian: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """The response (K, F) [mm/rad] to each coefficient of observations along unit ``direction``
    (K, 3) (base frame) of the TCP's error at readings ``q`` (K, 6) [rad] with ``jacobian``
    (K, 3, ANGLE_JOINTS): ``features`` seen along each direction."""
    along = np.einsum("kc,kcj->kj", direction, jacobian)[:, None, :]
    return features(q, along)[:, 0, :]


def fit_observed_angle_errors(
    design: np.ndarray, value_mm: np.ndarray, row: np.ndarray
) -> AngleErrors | None:
    """Angle errors of joints 1-3 from observations ``value_mm`` (K,) [mm] of the TCP's error with
    responses ``design`` (K, F) [mm/rad] (``features``, ``observed_features``), each of ``row``
    (K,) (row ``i`` in interleaved fold ``i mod FOLDS``); None unless they cut the table's fold
    error by ``MIN_GAIN`` and by a ``clear_gain``."""
    return fit_angle_errors_in_blocks(lambda: design_rows(design), value_mm, row)


def fit_angle_errors_in_blocks(design_blocks, value_mm: np.ndarray, row: np.ndarray) -> AngleErrors | None:
    """``fit_observed_angle_errors`` with the design given a block of observations at a time
    (``Folds``' ``design_blocks``): a million rows' responses are never whole."""
    return angle_errors_of(Folds(design_blocks, value_mm, row))


def angle_errors_of(folds) -> AngleErrors | None:
    """The angle errors of least fold error over the grid (``search``) from ``folds`` (``Folds``'
    ``noise``, ``gram``, ``moment``, ``error``, ``gains`` and ``table_error``); None unless they cut
    the table's fold error by ``MIN_GAIN`` and by a ``clear_gain``."""
    (length, sigma), best = min(search(folds).items(), key=lambda item: item[1])
    if best > (1.0 - MIN_GAIN) * folds.table_error or not clear_gain(*folds.gains(length, sigma)):
        return None
    prior = prior_variance(length, sigma)
    weights = posterior_mean(folds.gram, folds.moment, folds.noise, prior)
    covariance = posterior_covariance(folds.gram, folds.noise, prior)
    return AngleErrors(length, sigma, weights, covariance, best**2 / 3.0)
