"""Does a fit agree with what was stated before measuring? Statistics a calibration can take of
itself: its whitened residual against the instruments' stated noise (a chi-square), and how far
each parameter moved against what was known of it (its prior sigma: a table parameter's
manufacturing tolerance, the setup's rough values).

Residuals are whitened by the stated noise, so under the model with the noise as stated the sum of
squares of ``m`` rows fitted by ``k`` free unknowns is chi-square with ``m - k`` degrees of freedom,
and ``sqrt(chi2 / (m - k))`` is the residual in units of the stated noise (1 as stated, hundreds
when the rows come from another robot or cell).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import DOWNWEIGHTED_BELOW
from calib.special import gammaincc


@dataclass(frozen=True)
class NoiseTest:
    """The residual against the stated noise.

    Attributes
    ----------
    ratio : float
        RMS whitened residual of the rows the robust loss kept, per degree of freedom:
        ``sqrt(chi2 / dof)``, in stated noises.
    ratio_all : float
        The same over every row, the down-weighted ones included.
    chi2 : float
        Sum of the kept rows' squared whitened residuals.
    dof : int
        Kept rows minus free unknowns (at least 1).
    p_value : float
        Probability of a chi-square of ``dof`` degrees of freedom at or above ``chi2``.
    kept, rows : int
        Residual rows kept by the robust loss, and all of them.
    """

    ratio: float
    ratio_all: float
    chi2: float
    dof: int
    p_value: float
    kept: int
    rows: int


def chi_square_sf(chi2: float, dof: int) -> float:
    """``P(X >= chi2)`` for ``X`` chi-square with ``dof`` degrees of freedom: ``Q(dof/2, chi2/2)``,
    the regularised upper incomplete gamma function."""
    return gammaincc(dof / 2.0, float(chi2) / 2.0)


def noise_test(residuals: np.ndarray, weights: np.ndarray, n_free: int) -> NoiseTest:
    """The chi-square of a fit's whitened residual against the stated noise.

    Parameters
    ----------
    residuals : ndarray, shape (m,)
        The data rows' residuals at the solution, whitened by their stated noise (no prior rows).
    weights : ndarray, shape (m,)
        The robust loss's weights there (``sqrt(rho')``); a down-weighted row
        (``calibrate.DOWNWEIGHTED_BELOW``) stays out of the test.
    n_free : int
        Unknowns the fit estimated.

    Returns
    -------
    NoiseTest
    """
    r = np.asarray(residuals, float)
    kept = np.asarray(weights, float) ** 2 >= DOWNWEIGHTED_BELOW
    chi2 = float(np.sum(r[kept] ** 2))
    dof = max(int(kept.sum()) - n_free, 1)
    dof_all = max(r.size - n_free, 1)
    return NoiseTest(
        ratio=float(np.sqrt(chi2 / dof)),
        ratio_all=float(np.sqrt(np.sum(r**2) / dof_all)),
        chi2=chi2,
        dof=dof,
        p_value=chi_square_sf(chi2, dof),
        kept=int(kept.sum()),
        rows=int(r.size),
    )


def neighbour_agreement(q_rad: np.ndarray, residuals: np.ndarray, chunk: int = 512) -> float:
    """How alike the residuals of neighbouring poses are: an error of the robot that the model does
    not express varies smoothly with the pose, so neighbours share it; instrument noise does not.

    Parameters
    ----------
    q_rad : ndarray, shape (N, 6)
        The rows' joint angles [rad]; a row's neighbour is the nearest other row in the cosines and
        sines of its joints.
    residuals : ndarray, shape (N,) or (N, k)
        Each row's residual (any unit, the same for every row).
    chunk : int
        Rows whose distances to all others are held at once (memory ``chunk * N`` floats).

    Returns
    -------
    float
        ``sum_i r_i . r_nn(i) / sum_i |r_i|^2``: about 0 (within ``1 / sqrt(N k)``) for independent
        noise, near 1 for an error that is a smooth function of the pose.
    """
    r = np.asarray(residuals, float).reshape(len(q_rad), -1)
    f = np.column_stack([np.cos(q_rad), np.sin(q_rad)])
    sq = np.sum(f**2, axis=1)
    nearest = np.empty(len(f), int)
    for start in range(0, len(f), chunk):
        block = f[start : start + chunk]
        d = sq[start : start + chunk, None] - 2.0 * block @ f.T + sq[None, :]
        d[np.arange(len(block)), np.arange(start, start + len(block))] = np.inf
        nearest[start : start + chunk] = np.argmin(d, axis=1)
    total = float(np.sum(r**2))
    return float(np.sum(r * r[nearest]) / total) if total > 0 else 0.0


def excursions(x: np.ndarray, x_ref: np.ndarray, prior_sigma: np.ndarray, free: np.ndarray) -> np.ndarray:
    """How far each fitted unknown moved from where the fit started, in its prior sigmas.

    Parameters
    ----------
    x, x_ref : ndarray, shape (n,)
        The solution and the start (the robot file's table, the setup's rough values), internal
        units.
    prior_sigma : ndarray, shape (n,)
        What was known of each before measuring (1 sigma, internal units; inf: nothing).
    free : ndarray of bool, shape (n,)
        The fitted unknowns.

    Returns
    -------
    ndarray, shape (n,)
        ``|x - x_ref| / prior_sigma``; 0 where held or without a prior.
    """
    known = free & np.isfinite(prior_sigma)
    z = np.zeros(len(x))
    z[known] = np.abs(x[known] - x_ref[known]) / prior_sigma[known]
    return z


def wild_rows(errors: np.ndarray, factor: float) -> np.ndarray:
    """Rows whose error is ``factor`` times the median row's or more: readings no robot error
    explains (a 100 m cable among 1 m ones, a joint read ten turns off), which a fit that starts
    with least squares cannot shrug off.

    Parameters
    ----------
    errors : ndarray, shape (N,)
        Each row's error [mm], e.g. under the nominal table with the setup fitted.
    factor : float
        How many median errors make a row wild.

    Returns
    -------
    ndarray of int
        The wild rows, in order.
    """
    size = np.abs(np.asarray(errors, float))
    return np.flatnonzero(size >= factor * np.median(size))


@dataclass(frozen=True)
class DialGain:
    """How one gauge line's dial readings move the fitted TCP (``dial_gain``).

    Attributes
    ----------
    gain : ndarray, shape (3,)
        The TCP's offset from the line per mm of dial reading [mm/mm], base frame, across the line:
        the stated dial axis' component across the line where the axis is right, minus it where its
        sign is flipped, near zero where the dial does not read the tool's distance from this edge.
    sigma : float
        Its standard error (all three components together) [mm/mm].
    dof : int
        Rows less the three coefficients fitted: below a few, ``sigma`` itself is a guess.
    spread : float
        The readings' RMS beyond the line's constant and its trend along the line [mm]: what the
        gain is learnt from (near the readings' own noise, that noise dilutes it towards zero).
    """

    gain: np.ndarray
    sigma: float
    dof: int = 0
    spread: float = np.inf


def dial_gain(
    tcp: np.ndarray, point: np.ndarray, direction: np.ndarray, dial: np.ndarray, noise_mm: float = 0.0
) -> DialGain:
    """Regress a line's TCP offsets across it on the dial readings (with a constant and a term along
    the line, which a line's own fit absorbs).

    Parameters
    ----------
    tcp : ndarray, shape (n, 3)
        Fitted TCPs of the line's rows [mm], from a fit that did not use the dial readings.
    point, direction : ndarray, shape (3,)
        The fitted line [mm] and its unit direction.
    dial : ndarray, shape (n,)
        The rows' dial readings [mm].
    noise_mm : float
        The stated noise of a TCP's offset from its line, per direction across it [mm]: the
        residual's floor (a few rows can fit each other far better than the tool sits).

    Returns
    -------
    DialGain
    """
    rel = tcp - point
    along = rel @ direction
    offset = rel - along[:, None] * direction
    design = np.column_stack([np.ones(len(dial)), along, dial])
    coef = np.linalg.lstsq(design, offset, rcond=None)[0]
    dof = max(len(dial) - 3, 1)
    residual = max(float(np.sum((offset - design @ coef) ** 2)) / dof, 2.0 * noise_mm**2)
    var = np.linalg.pinv(design.T @ design)[2, 2]
    trend = np.linalg.lstsq(design[:, :2], dial, rcond=None)[0]
    spread = float(np.sqrt(np.mean((dial - design[:, :2] @ trend) ** 2)))
    return DialGain(coef[2], float(np.sqrt(residual * var)), len(dial) - 3, spread)
