"""Which joint-space terms a robot's data supports: k-fold cross-validation on the training rows.

A term earns its place only by predicting rows the fit did not see. The training rows are split
into k folds (``kfold``): within each placement (gauge line, tracker placement) the rows, in the
order they were measured, are cut into k contiguous blocks, and fold f leaves out block f of every
placement, so each fit keeps every placement and each left-out block is a stretch of poses the fit
did not visit. Each fold's fit is the calibration of all training rows (``calibrate.calibrate``:
identification, robust fit) moved by one Gauss-Newton step to the other folds' rows
(``cross_validated_errors``); the left-out rows are evaluated with the table, the terms and the
setup unknowns of that fit, as the contract evaluates hold-out rows. Against full refits per fold
on a real tracker set (IPA series B) the step gave the same ranking, gains within 0.5 %.

``select_terms`` then grows the model greedily: each round screens every candidate group (a
compliance, a harmonic's sine and cosine) on top of the groups kept so far, each fold's fit one
Gauss-Newton step from the round's calibration with the group's terms freed at 0
(``screened_errors``: the terms are small, so a refit lands where the step does; on a simulated
UR10 with a compliance the screen's scores are within 3.5 % of refits', on IPA series B it makes
the same choices), refits the best from the nominal robot, and keeps it if the
refit cuts the cross-validated RMS error by at least ``min_gain`` (5 %); it stops when none does.
A round costs one calibration, not one per candidate. Nothing outside the rows it is given is
looked at: a hold-out set or another series never enters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import Calibration, CalibrationOptions, WithPrior, calibrate
from calib.joint_terms import JointTerms, TermGroup
from calib.models import MeasurementModel

FOLDS = 5
MIN_GAIN = 0.05
"""Relative cut of the cross-validated RMS error a term group must bring to be kept."""


def kfold(placements: np.ndarray, k: int = FOLDS) -> list[np.ndarray]:
    """Left-out rows of each of ``k`` folds: per placement, contiguous blocks in row order.

    Parameters
    ----------
    placements : ndarray of int, shape (N,)
        The placement of each row (any ids; -1 is one more placement).
    k : int
        Number of folds, >= 2.

    Returns
    -------
    list of ndarray of int
        ``k`` ascending arrays of row indices; together every row exactly once.
    """
    blocks = [[] for _ in range(k)]
    for pid in np.unique(placements):
        rows = np.flatnonzero(placements == pid)
        for f, part in enumerate(np.array_split(rows, k)):
            blocks[f].append(part)
    return [np.sort(np.concatenate(b)).astype(int) for b in blocks]


def cross_validated_errors(
    model: MeasurementModel, folds: list[np.ndarray], options: CalibrationOptions
) -> tuple[np.ndarray, Calibration]:
    """Each row's error [mm] predicted by the calibration of the other folds.

    Each fold's calibration is one Gauss-Newton step from the calibration of all rows, on the
    other folds' residuals (and the prior rows) with that calibration's robust weights: leaving a
    fifth of the rows out moves the solution by a step small enough for the problem to be linear
    over it, and the identified parameters are those of all rows.

    Parameters
    ----------
    model : MeasurementModel
        The training rows, started at the nominal robot, with the terms to test.
    folds : list of ndarray of int
        Left-out rows of each fold (``kfold``).
    options : CalibrationOptions
        The pipeline's options.

    Returns
    -------
    errors : ndarray, shape (N,)
        ``row_error_mm`` of every row from the fit without its fold.
    calibration : Calibration
        The calibration of all rows the steps start from.
    """
    cal = calibrate(model, options)
    return _fold_errors(model, cal.x, cal.identified, cal.after.weights, folds), cal


def screened_errors(
    model: MeasurementModel,
    cal: Calibration,
    added: JointTerms,
    folds: list[np.ndarray],
) -> np.ndarray:
    """``cross_validated_errors`` of ``model`` with the terms ``added``, without refitting: each
    fold's fit is one Gauss-Newton step from ``cal`` (the calibration of ``model``, the added terms
    at 0) in the identified unknowns and the added terms, with ``cal``'s robust weights.

    The added terms are small beside the table's errors (micro-radians of yield, hundredths of a
    degree of harmonic), so the residuals are linear in them over the step and a refit from the
    nominal robot per candidate would land where the step does (``select_terms`` refits the one it
    keeps).

    Parameters
    ----------
    model : MeasurementModel
        The training rows with the terms kept so far (those of ``cal``).
    cal : Calibration
        The calibration of ``model``.
    added : JointTerms
        The model's terms followed by the terms to test (``pool.subset(kept + group)``).
    folds : list of ndarray of int
        Left-out rows of each fold (``kfold``).

    Returns
    -------
    ndarray, shape (N,)
        ``row_error_mm`` of every row from the step without its fold.
    """
    wide = model.with_terms(added)
    extra = len(wide.names) - len(model.names)
    x = np.concatenate([cal.x, np.zeros(extra)])
    free = np.concatenate([cal.identified, np.ones(extra, bool)])
    weights = np.ones(len(WithPrior(wide, wide.x0).rows))
    weights[: cal.after.weights.size] = cal.after.weights  # the added terms' prior rows come last
    return _fold_errors(wide, x, free, weights, folds)


def _fold_errors(model, x, free, weights, folds) -> np.ndarray:
    """Row errors [mm] of each fold's rows after one weighted Gauss-Newton step from ``x`` in the
    ``free`` unknowns on the other folds' rows and the prior rows (centred at ``model.x0``)."""
    prior = WithPrior(model, model.x0)
    r, jac = prior.residuals_and_jacobian(x)
    wj, wr = jac[:, free] * weights[:, None], r * weights
    # normal equations of all rows, less each fold's: a few unknowns, so one product for all folds
    # (the whitened, prior-regularised Jacobian is well enough conditioned to square)
    normal, gradient = wj.T @ wj, wj.T @ wr
    out = np.empty(len(model.samples))
    for rows in folds:
        left = np.isin(prior.rows, rows)
        a = normal - wj[left].T @ wj[left]
        step = np.linalg.lstsq(a, -(gradient - wj[left].T @ wr[left]), rcond=None)[0]
        x_fold = x.copy()
        x_fold[free] += step
        out[rows] = model.with_samples(model.samples.subset(rows)).row_error_mm(x_fold)
    return out


@dataclass(frozen=True)
class CandidateScore:
    """One line of the cross-validation table: in ``round`` (0: the starting model), the model of
    the groups kept so far plus ``label`` (None: nothing added) scored ``rmse_mm`` out of fold, a
    relative ``gain`` over the round's starting model, and whether it was ``kept``."""

    round: int
    label: str | None
    rmse_mm: float
    gain: float
    kept: bool


@dataclass(frozen=True)
class TermSelection:
    """What ``select_terms`` chose: the kept ``groups`` in order, every score it computed
    (``table``), the number of ``folds``, the ``min_gain`` asked of a group, and the
    ``calibration`` of all the rows with the kept groups (the pipeline's, with the options given)."""

    groups: tuple[TermGroup, ...]
    table: tuple[CandidateScore, ...]
    folds: int
    min_gain: float
    calibration: Calibration

    def rejected(self) -> dict[str, CandidateScore]:
        """Per candidate label not kept, its best score (for the reason it was held)."""
        kept = {g.label for g in self.groups}
        best: dict[str, CandidateScore] = {}
        for s in self.table:
            if (
                s.label is not None
                and s.label not in kept
                and (s.label not in best or s.gain > best[s.label].gain)
            ):
                best[s.label] = s
        return best


def select_terms(
    model: MeasurementModel,
    candidates: list[TermGroup],
    pool: JointTerms,
    options: CalibrationOptions,
    k: int = FOLDS,
    min_gain: float = MIN_GAIN,
) -> TermSelection:
    """Greedy forward selection of term groups by k-fold cross-validation (module docstring).

    Parameters
    ----------
    model : MeasurementModel
        The training rows (nothing else is looked at), started at the nominal robot; its own
        terms are replaced.
    candidates : list of TermGroup
        The groups to try.
    pool : JointTerms
        What the groups' terms need (the table for the torques, the masses): ``pool.subset``.
    options : CalibrationOptions
        The pipeline's options.
    k : int
        Folds.
    min_gain : float
        Relative cut of the cross-validated RMS error a group must bring.

    Returns
    -------
    TermSelection
    """
    folds = kfold(model.placement_ids(), k)

    def terms(groups) -> JointTerms:
        return pool.subset([t for g in groups for t in g.terms])

    def rmse(err: np.ndarray) -> float:
        return float(np.sqrt(np.mean(err**2)))

    kept: list[TermGroup] = []
    err, cal = cross_validated_errors(model.with_terms(terms(kept)), folds, options)
    current = rmse(err)
    table = [CandidateScore(0, None, current, 0.0, True)]
    left = list(candidates)
    while left:
        base = model.with_terms(terms(kept))
        score = {g.label: rmse(screened_errors(base, cal, terms(kept + [g]), folds)) for g in left}
        best = min(left, key=lambda g: score[g.label])
        accept = score[best.label] <= (1.0 - min_gain) * current
        if accept:  # the screen's pick, refitted from the nominal robot, must still earn its place
            err, refit = cross_validated_errors(model.with_terms(terms(kept + [best])), folds, options)
            score[best.label] = rmse(err)
            accept = score[best.label] <= (1.0 - min_gain) * current
        rnd = len(kept) + 1
        table += [
            CandidateScore(rnd, g.label, score[g.label], 1.0 - score[g.label] / current, accept and g is best)
            for g in left
        ]
        if not accept:
            break
        kept.append(best)
        left.remove(best)
        current, cal = score[best.label], refit
    return TermSelection(tuple(kept), tuple(table), k, min_gain, cal)
