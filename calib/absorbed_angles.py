"""Joint angle errors fitted beside the table they bend: the residual map of a calibration's own
model (``fit_model_map``; ``station calibrate`` stores it, the in-session targets keep the rows' map).

A calibration fits its table and setup to rows that carry a joint's cyclic error too: the fit moves
the table (on a drawstring cell also the anchor and the lines) to take out what of the error those
unknowns express, so the rows' residuals keep only the rest, and a map learnt from them alone
misses the part the table absorbed, which shows at the TCP where the rows do not look (a simulated
drawstring cell with ``UR10_LIKE``'s error: the rows keep 0.22 mm, the table is 0.73 mm off at a
program's poses near the measured ones, where the error itself is 0.38 mm). Here the coefficients
``w`` of the angle errors (``calib.angle_errors``) and a change ``dx`` of the calibration's free
table, tool and setup unknowns are fitted together to its whitened residuals ``r`` (the fit's own
metric), linearised at the solution::

    r + J dx + B w = noise,   w ~ N(0, prior),  dx free,

``J`` the model's Jacobian, ``B`` the angle errors' response through its columns of joints 1-3's
angle offsets (a link turning by ``dq`` moves each residual as its offset would). With ``dx``
profiled out, ``w`` is the Bayesian regression of ``-r`` on ``B`` less its projection on ``J``'s
columns, and ``dx = -J^+ (r + B w)``. Its part at ``w = 0``, ``-J^+ r``, is not nil: the calibration
weighed its rows by a robust loss (those the angle errors made large count less), and least squares
at the same rows lands elsewhere (a simulated drawstring cell with ``UR10_LIKE``'s error: 0.07 mm
at a program's poses, most of what the map left before it was added). Once ``w`` is fitted, one
Gauss-Newton step of the same unknowns on the rows turned by the angle errors relinearises ``dx``
where they put it. The table's and the tool's part of ``dx``, per coefficient and at ``w = 0``
(``ResidualMap.absorbed`` and ``absorbed_offset``), is added back where the map predicts, less the
rigid move of the base frame it makes of the calibration's rows: the lines and the anchor fitted
with the table alone stay where they are. The coefficients' covariance takes the
folds' mean square for the noise (not the rows' whole, which the angle errors mostly are), and the
bound the variance along the direction of the largest (the rows see the error along few).
Each joint's prior is then sharpened by the same folds onto its strongest order, or the joint made
quiet (``calib.angle_errors.sharpened``): the rows see each joint's error through one projection,
and the kernel's spread over neighbouring orders leaves part of a gear's one-order error unseen in
3-D (the simulated cells with ``UR10_LIKE``'s error, 20 seeds: 0.054 -> 0.036 mm at a program's
poses, 99.75 % inside the bound).

Beside the table, ``dx`` also holds the compliances of joints 2 and 3 under a load at the TCP
(``calib.compliance``: an arm's sag with its reach), on a prior of ``COMPLIANCE_PRIOR`` (rows of
the whitened fit in no fold): the table takes a sag's projection on the rows in, and errs by it
where they do not look (a simulated drawstring cell with ``UR10_LIKE``'s cyclic error and sag, 20
seeds, at a program's poses: 0.060 -> 0.054 mm, 0.055 -> 0.046 mm with 150 near poses). The
rows cannot tell a cell's sag from none (the folds' error moves by under 1 % either way, and a
cell's compliance scatters 1e-4 rad/m between seeds about a true 2e-4): so it has no stage of its
own and rides with the angle errors, costing 8 % on a cell whose robot has no sag (0.046 -> 0.050
mm; such a robot is rarer than one that sags).

A position instrument's rows (a tracker's) keep ``calib.residual_map.fit_rows_map``: they see the
whole error, and the table's change, unlike the angle errors, does not fall back away from the
rows (IPA UR10, trained on series C, tested on A, B and D: 0.450 mm with the rows' map, 0.616 mm
with this one; B with every 5th pose held out: 0.182 and 0.168 mm).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from calib.angle_errors import (
    ANGLE_JOINTS,
    FOLDS,
    HARMONICS,
    AngleErrors,
    angle_errors_of,
    features,
    posterior_covariance,
    posterior_mean,
    posterior_means,
    prior_variance,
    sharpened,
)
from calib.blocks import each_block
from calib.compliance import (
    COMPLIANCE_PRIOR,
    COMPLIANT_JOINTS,
    compliance_response,
    compliance_turn_rad,
    gravity_lever_m,
)
from calib.kinematics import N_DH, THETA, tcp_jacobian
from calib.map_rows import model_observations
from calib.models import thinned
from calib.residual_map import ABSORBED, TOOL, ResidualMap, fit_rows_map, frame_response, table_response
from calib.shared_error import fit_observed_shared, rms3

MAP_ROWS = 20_000
"""Rows the angle errors are fitted on at most: a larger calibration's fixed draw (the errors are
smooth over each joint's turn; their fit holds the residuals' response whole, 6 GB at 100,000
rows of a drawstring cell)."""

RCOND = 1e-6
"""Relative singular value below which the free unknowns' unit columns count as dependent (as
``calib.calibrate``'s ``rank_rtol``)."""


def residual_features(model, q: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """The response (m, F) of the model's whitened residuals to the angle errors' coefficients
    (``calib.angle_errors.features``' order): each residual's column of joints 1-3's angle offsets
    in ``jacobian`` (m, n) times the harmonics of the joint's reading in its row (``q`` (N, 6)
    [rad])."""
    along = jacobian[:, [4 * j + THETA for j in range(ANGLE_JOINTS)]][:, None, :]
    return features(q, along, model.rows)[:, 0, :]


def tool_response(model, x: np.ndarray) -> np.ndarray:
    """The TCP's move in the flange frame (3, n) [mm] per unit of each unknown (zero but for the
    model's tool columns; the tool is linear in them)."""
    out = np.zeros((TOOL, x.size))
    base = model.tcp_in_flange(x)
    for i in np.flatnonzero(getattr(model, "tool_mask", np.zeros(x.size, bool))):
        step = np.zeros(x.size)
        step[i] = 1.0
        out[:, i] = model.tcp_in_flange(x + step) - base
    return out


def fit_absorbed_angle_errors(
    model, x: np.ndarray, free: np.ndarray
) -> tuple[AngleErrors, np.ndarray, np.ndarray, float] | None:
    """Angle errors of joints 1-3 fitted with the change of the calibration's ``free`` (n,) table,
    tool and setup unknowns they call for (module docstring; joint-space terms stay, the errors
    are learnt on top of what they took), from ``model``'s whitened residuals and Jacobian at its
    solution ``x``: the errors (their ``rest_mm2`` in whitened units), the change (n + 2, F)
    [internal units, then the compliances' rad per m, per coefficient], the change at no angle
    error (n + 2,) [the same units: least squares' own solution, where the calibration's robust
    weights left it] and how many times the in-sample
    mean square the folds leave (>= 1); None unless they cut the folds' error (``ProfiledFolds``)
    by ``calib.angle_errors.MIN_GAIN``."""
    r, jac = model.residuals_and_jacobian(x)
    design = residual_features(model, model.samples.q, jac)
    columns = np.hstack([jac, residual_compliance(model, x, jac)])
    scale = np.linalg.norm(columns, axis=0)
    used = np.append(refitted(model, free, scale[: x.size]), scale[x.size :] > 0)
    prior = compliance_prior(scale[x.size :][used[x.size :]], int(used.sum()))
    folds = ProfiledFolds(design, r, columns[:, used] / scale[used], model.rows, prior)
    angles = angle_errors_of(folds)
    if angles is None:
        return None
    prior, best = sharpened(folds, angles)
    rest = best**2 / 3.0
    weights = posterior_mean(folds.gram, folds.moment, folds.noise, prior)
    covariance = posterior_covariance(folds.gram, rest, prior)
    angles = dataclasses.replace(angles, weights=weights, covariance=covariance, rest_mm2=rest)
    change, offset = np.zeros((scale.size, design.shape[1])), np.zeros(scale.size)
    change[used], offset[used] = folds.change / scale[used, None], folds.shift / scale[used]
    in_sample = folds.in_sample(angles.weights)
    return angles, -change, -offset, max(angles.rest_mm2 / max(in_sample, 1e-300), 1.0)


def compliance_prior(scale: np.ndarray, k: int) -> np.ndarray:
    """Rows (c, k) of the compliances' prior (``calib.compliance.COMPLIANCE_PRIOR``) on the last c
    of ``k`` unknowns whose columns were scaled to unit norm by ``scale`` (c,): the prior as
    residuals of the whitened fit, in no fold (always trained on)."""
    out = np.zeros((scale.size, k))
    out[:, k - scale.size :] = np.diag(1.0 / (COMPLIANCE_PRIOR * scale))
    return out


def residual_compliance(model, x: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """The response (m, 2) of the model's whitened residuals to the compliances of
    ``calib.compliance`` (``COMPLIANT_JOINTS``' columns of its angle offsets in ``jacobian`` (m, n)
    times each row's gravity lever arm [m] at its solution ``x``)."""
    lever = gravity_lever_m(model.dh(x), model.samples.q, model.tcp_in_flange(x))
    return jacobian[:, [4 * j + THETA for j in COMPLIANT_JOINTS]] * lever[model.rows]


def refitted(model, free: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Which unknowns (n,) are refitted with the angle errors: the calibration's ``free`` ones of the
    table, the tool and the setup that move its residuals (``scale`` (n,), their Jacobian's column
    norms, > 0)."""
    table_or_setup = (np.arange(scale.size) < N_DH) | model.setup_mask | model.tool_mask
    return np.asarray(free, bool) & table_or_setup & (scale > 0)


def refit_step(model, x: np.ndarray, free: np.ndarray) -> np.ndarray:
    """The Gauss-Newton step (n,) [internal units] of the ``refitted`` unknowns from ``x`` on
    ``model``'s whitened residuals (least squares): the profiled change relinearised where the
    angle errors' correction puts them."""
    r, jac = model.residuals_and_jacobian(x)
    scale = np.linalg.norm(jac, axis=0)
    used = refitted(model, free, scale)
    step = np.zeros(x.size)
    step[used] = np.linalg.lstsq(jac[:, used] / scale[used], -r, rcond=RCOND)[0] / scale[used]
    return step


def gram_lstsq(jj: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Least squares solutions (k, p) of columns whose Gram matrix is ``jj`` (k, k) for right-hand
    sides whose products with them are ``rhs`` (k, p): the columns' singular values below ``RCOND``
    times the largest dropped, as ``numpy.linalg.lstsq(rcond=RCOND)`` does (the Gram's eigenvalues
    are their squares)."""
    w, v = np.linalg.eigh(jj)
    keep = w > RCOND**2 * w.max()
    return v[:, keep] @ ((v[:, keep].T @ rhs) / w[keep, None])


def profiled(gram: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """From the Gram matrix (k + p, k + p) of columns ``[jac | rest]`` (the unknowns' k, then the
    design's and the residuals' p): the unknowns' change (k, p) that least squares takes of each
    of the rest, and the Gram matrix (p, p) of what is left of them."""
    change = gram_lstsq(gram[:k, :k], gram[:k, k:])
    left = gram[k:, k:] - gram[:k, k:].T @ change
    return change, (left + left.T) / 2.0


class ProfiledFolds:
    """``calib.angle_errors.Folds`` of whitened residuals whose table, tool and setup are refitted
    with the angle errors: each fold's residuals predicted from the other folds' rows, the
    unknowns' change fitted on those rows too (so the table alone's fold error is a refit's, not
    the calibration's in-sample residual). Each refit from the Gram matrices of the columns
    ``[jac | design | r]`` (one pass over the rows, per fold; a training set's is the whole's less
    its fold's), not from the rows again.

    Parameters
    ----------
    design : ndarray, shape (m, F)
        The residuals' response to the coefficients (``residual_features``).
    r : ndarray, shape (m,)
        The whitened residuals.
    jac : ndarray, shape (m, k)
        Their derivatives by the free table, tool and setup unknowns (columns of unit norm).
    row : ndarray, shape (m,)
        Each residual's row (row ``i`` in fold ``i mod FOLDS``).
    prior : ndarray, shape (c, k)
        Rows of a prior on the unknowns (their residuals and responses zero), in no fold.
    """

    def __init__(
        self, design: np.ndarray, r: np.ndarray, jac: np.ndarray, row: np.ndarray, prior: np.ndarray
    ):
        k, f = jac.shape[1], design.shape[1]
        held = [np.flatnonzero(row % FOLDS == g) for g in range(FOLDS)]
        columns = [np.hstack([prior, np.zeros((len(prior), f + 1))])] + [None] * FOLDS
        grams = [columns[0].T @ columns[0]] + [None] * FOLDS

        def fold(g: int, _: int) -> None:  # [jac | design | r] of fold g and its Gram matrix
            h, c = held[g], np.empty((held[g].size, k + f + 1))
            c[:, :k], c[:, k : k + f], c[:, -1] = jac[h], design[h], r[h]
            columns[g + 1], grams[g + 1] = c, c.T @ c

        each_block(FOLDS, 1, fold)
        whole = sum(grams)
        change, left = profiled(whole, k)
        self.change, self.shift = change[:, :f], change[:, f]
        self.gram, self.moment, self.squares = left[:f, :f], -left[:f, f], float(left[f, f])
        self.count = r.size + len(prior)
        self.noise = self.squares / self.count
        self.trained = np.empty((FOLDS, f, f)), np.empty((FOLDS, f))
        """Each fold's refit's Gram matrix and moment of the coefficients (from the other folds)."""
        self.parts = [None] * FOLDS

        def part(g: int, _: int) -> None:  # fold g's refit from the other folds' Gram matrix
            c = columns[g + 1]
            change, left = profiled(whole - grams[g + 1], k)
            self.trained[0][g], self.trained[1][g] = left[:f, :f], -left[:f, f]
            response = c[:, k : k + f] - c[:, :k] @ change[:, :f]
            value = c[:, :k] @ change[:, f] - c[:, k + f]
            self.parts[g] = (response, value, row[held[g]])

        each_block(FOLDS, 1, part)
        self.size = r.size
        self.table_error = float(np.sqrt(3.0 * sum(np.sum(v**2) for _, v, _ in self.parts) / self.size))

    def in_sample(self, weights: np.ndarray) -> float:
        """Mean square (whitened) of what the refitted unknowns and the coefficients ``weights``
        (F,) leave of the residuals, the rows' and the prior's."""
        return (self.squares - 2.0 * weights @ self.moment + weights @ self.gram @ weights) / self.count

    def error(self, length_deg: float, sigma_deg: float) -> float:
        """``calib.angle_errors.Folds.error`` (whitened units)."""
        return self.error_of(prior_variance(length_deg, sigma_deg))

    def error_of(self, prior: np.ndarray) -> float:
        """``error`` of the coefficients' ``prior`` (F,) [rad^2] variance."""
        squares, weights = 0.0, posterior_means(*self.trained, self.noise, prior)
        for w, (response, value, _) in zip(weights, self.parts, strict=True):
            squares += np.sum((value - response @ w) ** 2)
        return float(np.sqrt(3.0 * squares / self.size))

    def gains(self, length_deg: float, sigma_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """``calib.angle_errors.Folds.gains`` (whitened units)."""
        weights = posterior_means(*self.trained, self.noise, prior_variance(length_deg, sigma_deg))
        gain = [v**2 - (v - a @ w) ** 2 for w, (a, v, _) in zip(weights, self.parts, strict=True)]
        return np.concatenate(gain), np.concatenate([row for *_, row in self.parts])


def absorbed_of(model, x: np.ndarray, change: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``ResidualMap.absorbed`` (ABSORBED + 2, F) of a change of the unknowns and the compliances
    (n + 2, F) per coefficient, then ``ResidualMap.absorbed_offset`` (the last column) of their
    change ``offset`` (n + 2,) at no angle error: their table's and tool's part [rad, mm], the base
    frame's turn and shift [rad, mm] that take out the rigid move the angle errors and they make of
    the calibration's rows, then the compliances [rad per m]."""
    both, n = np.hstack([change, offset[:, None]]), x.size
    table = [both[:N_DH], tool_response(model, x) @ both[:n], np.zeros((6, both.shape[1]))]
    partial = np.vstack([*table, both[n:]])
    q, dh, tool = model.samples.q, model.dh(x), model.tcp_in_flange(x)
    p, jac = tcp_jacobian(dh, q, tool)
    joints = jac[:, :, [4 * j + THETA for j in range(ANGLE_JOINTS)]]
    response = np.concatenate([table_response(dh, q, p, jac), compliance_response(dh, q, tool, jac)], axis=2)
    moved = response @ partial
    moved[:, :, :-1] += features(q, joints)
    rigid = frame_response(p).reshape(-1, 6)
    frame = slice(ABSORBED - 6, ABSORBED)
    partial[frame] = -np.linalg.lstsq(rigid, moved.reshape(rigid.shape[0], -1), rcond=None)[0]
    return partial


def corrected(model, x: np.ndarray, angles: AngleErrors, change: np.ndarray, offset: np.ndarray):
    """The model on readings turned by the angle errors, and its unknowns ``x`` changed as they call
    for (``change`` (n + 2, F) per coefficient, ``offset`` (n + 2,) at none; the last two the
    compliances, which turn the readings too): where the rows' residuals are what both leave."""
    q, total = model.samples.q, offset + change @ angles.weights
    turned = compliance_turn_rad(model.dh(x), q, model.tcp_in_flange(x), total[x.size :])
    for j in range(ANGLE_JOINTS):
        turned[:, j] += turn_rad(angles.weights, q, j)
    samples = dataclasses.replace(model.samples, q=turned)
    return model.with_samples(samples), x + total[: x.size]


def turn_rad(weights: np.ndarray, q: np.ndarray, joint: int) -> np.ndarray:
    """Joint ``joint``'s angle error [rad] (N,) at readings ``q`` (N, 6) [rad] of coefficients
    ``weights`` (F,) (``calib.angle_errors.features``' order)."""
    order = np.arange(1, HARMONICS + 1)
    angle = q[:, joint, None] * order
    w = weights[2 * HARMONICS * joint : 2 * HARMONICS * (joint + 1)]
    return np.cos(angle) @ w[:HARMONICS] + np.sin(angle) @ w[HARMONICS:]


def fit_model_map(model, x: np.ndarray, free: np.ndarray) -> ResidualMap | None:
    """The residual map of a calibration's ``model`` at its solution ``x`` with its ``free`` (n,)
    unknowns (``Calibration.identified``): the angle errors fitted beside the table they bend
    (``fit_absorbed_angle_errors``), then the shared error of what both
    leave of the rows' observations (``calib.map_rows``; ``calib.residual_map.fit_rows_map``'s
    second stage; a drawstring cell's on at most ``MAP_ROWS`` of its rows); None where neither cuts
    the folds' error."""
    if model.kind == "position":  # the table's change does not fall back far from the rows (module notes)
        return fit_rows_map(model_observations(model, x), model.dh(x), model.tcp_in_flange(x))
    model = thinned(model, MAP_ROWS)  # the errors are smooth over each joint's turn
    rows = model_observations(model, x)
    if rows.q.shape[0] < 2 * FOLDS or not np.any(rows.value_mm):
        return None
    table = rms3(rows.value_mm[:, None])
    found = fit_absorbed_angle_errors(model, x, free)
    angles = absorbed = offset = None
    if found is not None:
        angles, change, shift, inflation = found
        turned, x_turned = corrected(model, x, angles, change, shift)
        step = refit_step(turned, x_turned, free)
        shift[: step.size] += step
        left = model_observations(turned, x_turned + step)
        rows = dataclasses.replace(left, q=rows.q)
        rest_mm2 = float(np.mean(rows.value_mm**2)) * inflation
        angles = dataclasses.replace(angles, rest_mm2=rest_mm2)
        absorbed = absorbed_of(model, x, change, shift)
        absorbed, offset = absorbed[:, :-1], absorbed[:, -1]
    shared = fit_observed_shared(rows, rows.value_mm)
    if angles is None and shared is None:
        return None
    best = shared.cv_rmse_mm if shared is not None else float(np.sqrt(3.0 * angles.rest_mm2))
    dh, tool = np.asarray(model.dh(x), float), np.asarray(model.tcp_in_flange(x), float)
    return ResidualMap(dh, tool, angles, shared, best, table, absorbed, offset)
