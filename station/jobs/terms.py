"""The robot's joint-space terms in the station's files: which a calibration fits (``--model``)
and which a robot file carries (``calib.joint_terms``).

``--model`` names the terms a calibration may fit:

- ``geometric``: the D-H table alone;
- ``compliance``: plus each load-bearing joint yielding under gravity (needs the robot file's link
  masses; the setup's payload joins them);
- ``full``: plus the first and second harmonics of every joint's angle;
- ``auto``: ``full``'s groups judged by cross-validation on blocked folds of the training rows (one
  region of joint space left out at a time: what the table does away from the poses it was fitted
  on, ``calib.selection``): the compliances together, as a prior, kept when determined, plausible
  and not harmful; then, likewise together, the first harmonics of the joints whose rows cover their
  whole turn (an encoder's once-per-turn error, which such rows interpolate at every angle:
  ``calib.joint_terms.whole_turn_joints``); each other harmonic only if determined at five sigma
  and it cuts the error by 5 %.

Whatever the data cannot determine is held by the pipeline with its reason, as a table parameter is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import Calibration, CalibrationOptions, WithPrior, coarse_draw
from calib.joint_terms import (
    COMPLIANCE,
    JointTerms,
    LinkMasses,
    Term,
    TermGroup,
    compliance_group,
    harmonic_group,
    load_bearing_joints,
    whole_turn_joints,
)
from calib.kinematics import N_JOINTS, dh_table
from calib.methods import TERM_MODELS
from calib.models import MeasurementModel, spread_rows
from calib.selection import TermSelection, blocked_folds, fitted_errors, nominal_errors, rms, select_terms

MODELS = TERM_MODELS
ARM_JOINTS = (1, 2)
"""Joints (0-based) named for compliance when the robot file gives no masses to find them by."""
NO_MASSES = (
    "the robot file gives no link masses (mass_kg and com_mm of every joint): no gravity torque "
    "to yield under"
)
NOT_CHOSEN = (
    "--model auto: it changes the blocked cross-validated error of the training rows by "
    "{change:+.1%} ({base:.4f} -> {rmse:.4f} mm); a term must cut it by {need:.0%}"
)
PRIOR_LEFT = "--model auto: {reason}"
WORSE_THAN_NOMINAL = (
    "the calibrated model predicts poses away from those it was fitted on worse than the nominal "
    "table ({rmse:.3f} mm against {nominal:.3f} mm, cross-validated on {scheme}): do not use this "
    "table; measure configurations spread over every joint's range"
)
DRAWN = ", on {k} of the {n} rows (a fixed draw spread over all of them)"
TOO_FEW = (
    "--model auto: {n} samples leave too few per fold ({per_fold}) for the {needed} unknowns of "
    "every candidate term: the table alone is fitted"
)


@dataclass(frozen=True)
class Candidates:
    """What ``--model`` offers a calibration: the term ``groups``, the ``pool`` that builds their
    terms, and the terms ``held`` before any fit, with the reason."""

    groups: tuple[TermGroup, ...]
    pool: JointTerms
    held: dict[str, str]


def candidates(kind: str, model: MeasurementModel, links: LinkMasses | None) -> Candidates:
    """The term groups ``--model kind`` offers on a training ``model`` (started at the nominal
    table): compliances of the joints that carry the arm over its rows (by the masses; without
    them, held), and for ``full``/``auto`` both harmonics of every joint."""
    dh = dh_table(model.x0)
    pool = JointTerms((), dh, links)
    if kind == "geometric":
        return Candidates((), pool, {})
    held = {}
    if links is None:
        groups = []
        held = {Term(j, COMPLIANCE).name: NO_MASSES for j in ARM_JOINTS}
    else:
        groups = [compliance_group(j) for j in load_bearing_joints(dh, model.samples.q, links)]
    if kind != "compliance":
        groups += [harmonic_group(j, h) for j in range(N_JOINTS) for h in (1, 2)]
    return Candidates(tuple(groups), pool, held)


@dataclass(frozen=True)
class TermChoice:
    """The training ``model`` with the chosen terms, the cross-validation behind the choice
    (``auto``), the terms held before fitting (with reasons) and any ``warning``."""

    model: MeasurementModel
    selection: TermSelection | None
    held: dict[str, str]
    warning: str | None = None
    drawn: bool = False
    """Whether ``auto`` chose on a draw of the rows (``choose_terms``), not on all of them."""

    @property
    def calibration(self) -> Calibration | None:
        """The white calibration of ``model`` (no discrepancy) where ``auto`` already ran it."""
        return self.selection.calibration if self.selection is not None and not self.drawn else None


def choose_terms(kind: str, model: MeasurementModel, links: LinkMasses | None, unknowns: int) -> TermChoice:
    """The terms of ``--model kind`` on the training ``model`` (``unknowns``: what the table and
    setup alone leave to determine); ``auto`` cross-validates on these rows only, and on more than
    ``calib.calibrate.COARSE_ROWS`` of them on that many (``coarse_draw``: the fixed draw spread
    over every configuration that the robust fits start from), the chosen terms then fitted
    on all rows: a term's cross-validated gain is a model check, the same on the draw."""
    offer = candidates(kind, model, links)
    every = [t for g in offer.groups for t in g.terms]
    if kind != "auto":
        return TermChoice(model.with_terms(offer.pool.subset(every)), None, offer.held)
    everyone, model = model, coarse_draw(model)
    n = len(model.samples)
    folds, scheme = blocked_folds(model.samples.q)
    if model is not everyone:
        scheme += DRAWN.format(k=n, n=len(everyone.samples))
    per_fold = n - max(len(f) for f in folds)
    if per_fold < unknowns + len(every):
        warning = TOO_FEW.format(n=n, per_fold=per_fold, needed=unknowns + len(every))
        return TermChoice(everyone, None, offer.held, warning)
    compliances = [g for g in offer.groups if all(t.key == COMPLIANCE for t in g.terms)]
    turns = [harmonic_group(j, 1) for j in whole_turn_joints(everyone.samples.q)]
    prior = (compliances, [g for g in offer.groups if g in turns])
    others = [g for g in offer.groups if g not in compliances + prior[1]]
    white = CalibrationOptions(correlated=False)  # the rule was chosen on white fits
    selection = select_terms(model, others, offer.pool, white, folds=folds, prior=prior, scheme=scheme)
    kept = [t for g in selection.groups for t in g.terms]
    held = dict(offer.held)
    by_label = {g.label: g for g in offer.groups}
    for label, score in selection.rejected().items():
        reason = (
            PRIOR_LEFT.format(reason=score.reason)
            if score.reason
            else NOT_CHOSEN.format(
                rmse=score.rmse_mm,
                base=score.rmse_mm / (1.0 - score.gain),
                change=-score.gain,
                need=selection.min_gain,
            )
        )
        held.update(dict.fromkeys((t.name for t in by_label[label].terms), reason))
    drawn = model is not everyone  # its calibration is the draw's, not the model's
    return TermChoice(everyone.with_terms(offer.pool.subset(kept)), selection, held, drawn=drawn)


def carry_over_warnings(model: MeasurementModel, cal: Calibration) -> list[str]:
    """A warning when the calibration ``cal`` of ``model`` predicts left-out regions of joint space
    worse than the nominal table does on the same blocked folds. Both are scored on the rows the
    calibration kept (its down-weighted gross readings left out, as its fit left them out): a few
    per cent of 2-5 mm readings otherwise decide the comparison and called good tables worse than
    the nominal one. On more than ``COARSE_ROWS`` rows both on that many (``coarse_draw``'s)."""
    weights, kept = None, np.ones(len(model.samples), bool)
    if cal.after.weights.size == len(WithPrior(model, model.x0).rows):  # not a subset's fit (MCS)
        weights = cal.after.weights
        kept[cal.downweighted] = False
    model, weights, kept = _drawn(model, weights, kept)
    folds, scheme = blocked_folds(model.samples.q)
    if len(model.samples) - max(len(f) for f in folds) < int(cal.identified.sum()):
        return []
    mine = rms(fitted_errors(model, cal, folds, weights)[kept])
    nominal = rms(nominal_errors(model, cal, folds)[kept])
    if mine < nominal:
        return []
    return [WORSE_THAN_NOMINAL.format(rmse=mine, nominal=nominal, scheme=scheme)]


def _drawn(model: MeasurementModel, weights: np.ndarray | None, kept: np.ndarray):
    """``coarse_draw(model)`` with its residual rows' ``weights`` (the model's rows', then the prior
    rows'; None: none) and its sample rows' ``kept`` (N,) flags."""
    drawn = coarse_draw(model)
    if drawn is model:
        return model, weights, kept
    pick = spread_rows(len(model.samples), len(drawn.samples))
    if weights is not None:
        mine = np.isin(model.rows, pick)  # the drawn model's residual rows, in its order
        weights = np.concatenate([weights[: model.rows.size][mine], weights[model.rows.size :]])
    return drawn, weights, kept[pick]
