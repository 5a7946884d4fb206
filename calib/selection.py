"""Which joint-space terms a robot's data supports: cross-validation on the training rows.

A term earns its place only by predicting rows the fit did not see. ``station calibrate --model
auto`` uses blocked folds (below, ``blocked_folds``); by default the training rows are split
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

Row folds interleave with the training poses and so measure interpolation; what a user needs is
accuracy at poses the calibration never saw. ``blocked_folds`` therefore leaves out whole regions:
``FOLDS`` regions of joint space (k-means on joints 1-3, which decide where the arm is), for a
tracker set and a drawstring session alike. Physically grounded terms (a joint yielding under
gravity: its sign and size are known before measuring) are treated as a prior rather than a
candidate (``prior_groups``): they enter together, kept when the data determine them (joint
chi-square beyond ``DETERMINED_P``), each value plausible (``implausible``) and the blocked
cross-validated error not significantly worse (``not_harmful``). Prior groups come in stages, each
judged on top of those kept before it (``station calibrate`` has two: the compliances, then the
first harmonics of the joints whose rows cover their whole turn). The other groups (harmonics) must
be determined as well (the best of m screened: p below ``DISCOVERY_P / m``) and earn ``min_gain``.
On the real UR10 (IPA series A-D) row folds gave J2's compliance a 1-9 % gain and blocked folds 2-30 %, and
compliance alone was the best fixed model on every "train one, test three" split.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import Calibration, CalibrationOptions, SetupFit, WithPrior, calibrate, fit_setup
from calib.joint_terms import COMPLIANCE, COMPLIANCE_PRIOR, JointTerms, TermGroup
from calib.kmeans import REGION_JOINTS, region_folds
from calib.lm import fold_normal_equations
from calib.models import MeasurementModel
from calib.special import gammaincc

FOLDS = 5
MIN_GAIN = 0.05
"""Relative cut of the cross-validated RMS error a term group must bring to be kept."""
DETERMINED_P = 0.0027
"""A group is determined when its values' chi-square (their covariance) has a smaller p (three
sigma): on data without the term it passes about once in 400 sessions."""
DISCOVERY_P = 5.7e-7
"""A harmonic is determined when its chi-square p is below this (five sigma) divided by the groups
screened with it: no physics predicts it, and where the table's held parameters leave a misfit the
covariance overstates what the rows say (a clean simulated three-line cell kept a J3 second
harmonic at p 3e-5). On the real UR10 the drawstring path of series A keeps J5's first harmonic;
series D's J3 first harmonic (-5.9 % blocked error) falls short."""
HARM_SIGMAS = 2.0
"""A prior group is harmful when it raises the mean squared blocked cross-validated error by more
than this many standard errors of the paired row differences."""
UNDETERMINED = (
    "it cuts the blocked cross-validated error by {gain:.1%}, but the data do not determine its "
    "values (p {p:.2g}; five sigma for the best of {m} groups screened needs p below {need:.1e})"
)
"""Why a harmonic that earned its cut was left (``CandidateScore.reason``); the screen ends there."""
SCREEN_ENDED = (
    "it cuts the blocked cross-validated error by {gain:.1%}, but the screen ended at {best}, which "
    "cut more and was not determined"
)


def _left_because(undetermined: str | None, is_best: bool, gain: float, min_gain: float, best: str):
    """A screened group's reason when the round's best earned its cut but was not determined."""
    if undetermined is None:
        return None
    if is_best:
        return undetermined
    return SCREEN_ENDED.format(gain=gain, best=best) if gain >= min_gain else None


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


def blocked_folds(q: np.ndarray) -> tuple[list[np.ndarray], str]:
    """``region_folds`` of ``q`` (N, 6) [rad] and their description for the report.

    Not one gauge line out at a time: with the three lines of a typical session, the table fitted
    on two extrapolates so far to the third that a harmonic of a wrist joint cut the left-out error
    by 5 % on every clean simulated cell tried (``benchmarks/terms_false_positives.py``)."""
    folds = region_folds(q, FOLDS)
    return folds, f"{len(folds)} regions of joint space (k-means on joints 1-{REGION_JOINTS}), one left out"


def cross_validated_errors(
    model: MeasurementModel,
    folds: list[np.ndarray],
    options: CalibrationOptions,
    held: SetupFit | None = None,
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
    held : SetupFit, optional
        The same rows' setup fit with other terms (``calib.calibrate.fit_setup``'s ``held``).

    Returns
    -------
    errors : ndarray, shape (N,)
        ``row_error_mm`` of every row from the fit without its fold.
    calibration : Calibration
        The calibration of all rows the steps start from.
    """
    model = model.by_axes()
    cal = calibrate(model, options, start=fit_setup(model, options, held))
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
    ``free`` unknowns on the other folds' rows and the prior rows (centred at ``model.x0``), with
    the model's TCPs composed by ``kinematics.frame_axes``."""
    model = model.by_axes()
    prior = WithPrior(model, model.x0)
    r, jac = prior.residuals_and_jacobian(x)
    wr = r * weights
    # normal equations of all rows, less each fold's: a few unknowns, so one pass for all folds
    # (the whitened, prior-regularised Jacobian is well enough conditioned to square); the prior
    # rows (row -1) in a set of their own
    fold_of_row = np.full(len(model.samples), len(folds))
    for f, rows in enumerate(folds):
        fold_of_row[rows] = f
    label = np.where(prior.rows >= 0, fold_of_row[prior.rows], len(folds))
    fold_normal, fold_gradient = fold_normal_equations(jac, free, weights, wr, label, len(folds) + 1)
    normal, gradient = fold_normal.sum(axis=0), fold_gradient.sum(axis=0)
    out = np.empty(len(model.samples))
    for f, rows in enumerate(folds):
        step = np.linalg.lstsq(normal - fold_normal[f], -(gradient - fold_gradient[f]), rcond=None)[0]
        x_fold = x.copy()
        x_fold[free] += step
        out[rows] = model.with_samples(model.samples.subset(rows)).row_error_mm(x_fold)
    return out


def fitted_errors(
    model: MeasurementModel, cal: Calibration, folds: list[np.ndarray], weights: np.ndarray | None = None
) -> np.ndarray:
    """``cross_validated_errors`` from a calibration already made (``cal`` of ``model``): each fold's
    rows [mm] after one Gauss-Newton step on the other folds' rows, weighted by ``weights`` (the
    model's and the prior's rows; None: every row alike)."""
    if weights is None:
        weights = np.ones(len(WithPrior(model, model.x0).rows))
    return _fold_errors(model, cal.x, cal.identified, weights, folds)


def nominal_errors(model: MeasurementModel, cal: Calibration, folds: list[np.ndarray]) -> np.ndarray:
    """Each row's error [mm] with the nominal table, the setup unknowns fitted on the other folds (one
    Gauss-Newton step from ``cal``'s setup-only fit): what not calibrating gives on the same folds."""
    free = cal.identified & model.setup_mask
    weights = np.ones(len(WithPrior(model, model.x0).rows))
    return _fold_errors(model, cal.before.x, free, weights, folds)


def rms(err: np.ndarray) -> float:
    """Root mean square of row errors [mm]."""
    return float(np.sqrt(np.mean(err**2)))


def not_harmful(err: np.ndarray, base: np.ndarray) -> bool:
    """Whether the row errors ``err`` (N,) [mm] raise the mean squared error over ``base`` (N,) by no
    more than ``HARM_SIGMAS`` standard errors of the paired differences."""
    d = err**2 - base**2
    return bool(d.mean() <= HARM_SIGMAS * d.std() / np.sqrt(d.size))


def implausible(value: float, sigma: float) -> str | None:
    """Why a compliance [urad / (N m)] determined to ``sigma`` is not a joint yielding under gravity,
    or None: it yields against gravity beyond three sigma, or is softer than the prior allows
    (``COMPLIANCE_PRIOR``: a joint stiffness below about 3e4 N m/rad)."""
    if value < -3.0 * sigma:
        return f"{value:.3g} +- {sigma:.2g} urad/(N m): yields against gravity"
    if value > COMPLIANCE_PRIOR:
        return f"{value:.3g} +- {sigma:.2g} urad/(N m): softer than the prior allows ({COMPLIANCE_PRIOR:g})"
    return None


def term_estimates(model: MeasurementModel, cal: Calibration) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The model's terms' values (K,), sigmas (K,, NaN where held) and the covariance of the
    identified ones (internal units)."""
    k = np.array([cal.names.index(n) for n in model.terms.names], int)
    position = np.cumsum(cal.identified) - 1
    seen = k[cal.identified[k]]
    return cal.x[k], cal.sigma[k], cal.covariance[np.ix_(position[seen], position[seen])]


def determined_p(model: MeasurementModel, cal: Calibration, terms: int) -> float:
    """Chi-square p of the last ``terms`` of the model's terms being all zero (their values and
    covariance in ``cal``; 1 where none is identified)."""
    value, sigma, cov = term_estimates(model, cal)
    seen = np.isfinite(sigma)
    mine = np.zeros(seen.size, bool)
    mine[seen.size - terms :] = True
    v = value[seen & mine]
    if not v.size:
        return 1.0
    c = cov[np.ix_(mine[seen], mine[seen])]
    return gammaincc(v.size / 2, float(v @ np.linalg.solve(c, v)) / 2)  # chi-square's survival


@dataclass(frozen=True)
class CandidateScore:
    """One line of the cross-validation table: in ``round`` (0: the starting model), the model of
    the groups kept so far plus ``label`` (None: nothing added; prior groups entering together
    are joined by " + ") scored ``rmse_mm`` out of fold, a relative ``gain`` over the round's
    starting model, whether it was ``kept``, and for a prior group the ``reason`` it was left."""

    round: int
    label: str | None
    rmse_mm: float
    gain: float
    kept: bool
    reason: str | None = None


@dataclass(frozen=True)
class TermSelection:
    """What ``select_terms`` chose: the kept ``groups`` in order, every score it computed
    (``table``), the number of ``folds``, the ``min_gain`` asked of a group, and the
    ``calibration`` of all the rows with the kept groups (the pipeline's, with the options given);
    ``scheme`` says what the folds leave out and ``nominal_rmse_mm`` is the nominal table's error on
    the same folds."""

    groups: tuple[TermGroup, ...]
    table: tuple[CandidateScore, ...]
    folds: int
    min_gain: float
    calibration: Calibration
    scheme: str = "contiguous blocks of each placement's rows"
    nominal_rmse_mm: float | None = None

    @property
    def rmse_mm(self) -> float:
        """The chosen model's cross-validated RMS error [mm]."""
        return [s.rmse_mm for s in self.table if s.kept][-1]

    def rejected(self) -> dict[str, CandidateScore]:
        """Per candidate label not kept, its best score (for the reason it was held)."""
        kept = {g.label for g in self.groups}
        best: dict[str, CandidateScore] = {}
        for s in self.table:
            for label in [] if s.label is None else s.label.split(" + "):
                if label not in kept and (label not in best or s.gain > best[label].gain):
                    best[label] = s
        return best


def _terms(pool: JointTerms, groups) -> JointTerms:
    return pool.subset([t for g in groups for t in g.terms])


def prior_groups(
    model: MeasurementModel,
    kept: list[TermGroup],
    groups: list[TermGroup],
    pool: JointTerms,
    options: CalibrationOptions,
    folds: list[np.ndarray],
    base: np.ndarray,
    round_: int,
    held: SetupFit | None = None,
) -> tuple[list[TermGroup], tuple[np.ndarray, Calibration] | None, list[CandidateScore]]:
    """Physically grounded groups entering together on top of the ``kept`` ones: each implausible
    compliance is dropped (``implausible``) and the rest refitted; what is left is kept when its
    values are determined (chi-square p below ``DETERMINED_P``) and the cross-validated errors stay
    ``not_harmful`` beside ``base`` (N,), the kept model's. Returns the groups kept, their errors and
    calibration (None if none kept) and the table's lines (``round_``). ``held``: the rows' setup
    fit (``cross_validated_errors``)."""
    current, scores = list(groups), []
    while current:
        wide = model.with_terms(_terms(pool, kept + current))
        err, cal = cross_validated_errors(wide, folds, options, held)
        gain = 1.0 - rms(err) / rms(base)
        value, sigma, _ = term_estimates(wide, cal)
        at = np.cumsum([len(_terms(pool, kept))] + [len(g.terms) for g in current])[:-1]
        bad = {
            g.label: implausible(value[a], sigma[a])
            for g, a in zip(current, at, strict=True)
            if g.terms[0].key == COMPLIANCE
        }
        bad = {label: why for label, why in bad.items() if why}
        if bad:
            scores += [
                CandidateScore(round_, label, rms(err), gain, False, why) for label, why in bad.items()
            ]
            current = [g for g in current if g.label not in bad]
            continue
        p = determined_p(wide, cal, len(_terms(pool, current)))
        reason = None
        if p > DETERMINED_P:
            reason = f"not determined by the rows (chi-square p {p:.2g}, above {DETERMINED_P})"
        elif not not_harmful(err, base):
            reason = f"raises the blocked cross-validated error ({rms(base):.4f} -> {rms(err):.4f} mm)"
        label = " + ".join(g.label for g in current)
        scores.append(CandidateScore(round_, label, rms(err), gain, reason is None, reason))
        return (current, (err, cal), scores) if reason is None else ([], None, scores)
    return [], None, scores


def select_terms(
    model: MeasurementModel,
    candidates: list[TermGroup],
    pool: JointTerms,
    options: CalibrationOptions,
    k: int = FOLDS,
    min_gain: float = MIN_GAIN,
    *,
    folds: list[np.ndarray] | None = None,
    prior: tuple[list[TermGroup], ...] = (),
    scheme: str = "contiguous blocks of each placement's rows",
) -> TermSelection:
    """Greedy forward selection of term groups by cross-validation (module docstring).

    Parameters
    ----------
    model : MeasurementModel
        The training rows (nothing else is looked at), started at the nominal robot; its own
        terms are replaced.
    candidates : list of TermGroup
        The groups to try, each of which must cut the error by ``min_gain``.
    pool : JointTerms
        What the groups' terms need (the table for the torques, the masses): ``pool.subset``.
    options : CalibrationOptions
        The pipeline's options.
    k : int
        Folds (``kfold``) where ``folds`` is not given.
    min_gain : float
        Relative cut of the cross-validated RMS error a group must bring.
    folds : list of ndarray of int, optional
        Left-out rows of each fold (``blocked_folds``); default ``kfold`` of the placements.
    prior : tuple of list of TermGroup
        Physically grounded groups in stages, each judged together on top of the stages kept before
        it (``prior_groups``), before any candidate.
    scheme : str
        What the folds leave out, for the report.

    Returns
    -------
    TermSelection
    """
    folds = kfold(model.placement_ids(), k) if folds is None else folds
    model = model.by_axes()  # every fit and fold step below on the faster frame composition
    kept: list[TermGroup] = []
    held = fit_setup(model.with_terms(_terms(pool, kept)), options)  # every fit's below: terms at zero
    err, cal = cross_validated_errors(model.with_terms(_terms(pool, kept)), folds, options, held)
    nominal = rms(nominal_errors(model.with_terms(_terms(pool, kept)), cal, folds))
    current = rms(err)
    table = [CandidateScore(0, None, current, 0.0, True)]
    for stage in prior:
        if not stage:
            continue
        found, fit, lines = prior_groups(
            model, kept, list(stage), pool, options, folds, err, table[-1].round + 1, held
        )
        table += lines
        if fit is not None:
            kept += found
            err, cal = fit
            current = rms(err)
    left = list(candidates)
    while left:
        base = model.with_terms(_terms(pool, kept))
        score = {g.label: rms(screened_errors(base, cal, _terms(pool, kept + [g]), folds)) for g in left}
        best = min(left, key=lambda g: score[g.label])
        accept = score[best.label] <= (1.0 - min_gain) * current
        why = None
        if accept:  # the screen's pick, refitted from the nominal robot, must still earn its place
            wide = model.with_terms(_terms(pool, kept + [best]))
            err, refit = cross_validated_errors(wide, folds, options, held)
            score[best.label] = rms(err)
            # the best of len(left) screened: its p must pass for all of them (Bonferroni)
            p, need = determined_p(wide, refit, len(best.terms)), DISCOVERY_P / len(left)
            earns = score[best.label] <= (1.0 - min_gain) * current
            accept = earns and p <= need
            if earns and not accept:
                why = UNDETERMINED.format(gain=1.0 - score[best.label] / current, p=p, need=need, m=len(left))
        rnd = table[-1].round + 1
        table += [
            CandidateScore(
                rnd,
                g.label,
                score[g.label],
                1.0 - score[g.label] / current,
                accept and g is best,
                _left_because(why, g is best, 1.0 - score[g.label] / current, min_gain, best.label),
            )
            for g in left
        ]
        if not accept:
            break
        kept.append(best)
        left.remove(best)
        current, cal = score[best.label], refit
    return TermSelection(tuple(kept), tuple(table), len(folds), min_gain, cal, scheme, nominal)
