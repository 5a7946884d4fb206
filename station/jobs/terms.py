"""The robot's joint-space terms in the station's files: which a calibration fits (``--model``)
and which a robot file carries (``calib.joint_terms``).

``--model`` names the terms a calibration may fit:

- ``geometric``: the D-H table alone;
- ``compliance``: plus each load-bearing joint yielding under gravity (needs the robot file's link
  masses; the setup's payload joins them);
- ``full``: plus the first and second harmonics of every joint's angle;
- ``auto``: of ``full``'s groups, those that cut the cross-validated error of the training rows by
  at least 5 % (``calib.selection``).

Whatever the data cannot determine is held by the pipeline with its reason, as a table parameter is.
"""

from __future__ import annotations

from dataclasses import dataclass

from calib.calibrate import Calibration, CalibrationOptions
from calib.joint_terms import (
    COMPLIANCE,
    JointTerms,
    LinkMasses,
    Term,
    TermGroup,
    compliance_group,
    harmonic_group,
    load_bearing_joints,
)
from calib.kinematics import N_JOINTS, dh_table
from calib.methods import TERM_MODELS
from calib.models import MeasurementModel
from calib.selection import FOLDS, TermSelection, select_terms

MODELS = TERM_MODELS
ARM_JOINTS = (1, 2)
"""Joints (0-based) named for compliance when the robot file gives no masses to find them by."""
NO_MASSES = (
    "the robot file gives no link masses (mass_kg and com_mm of every joint): no gravity torque "
    "to yield under"
)
NOT_CHOSEN = (
    "--model auto: it changes the cross-validated error of the training rows by {change:+.1%} "
    "({base:.4f} -> {rmse:.4f} mm); a term must cut it by {need:.0%}"
)
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

    @property
    def calibration(self) -> Calibration | None:
        """The pipeline's calibration of ``model`` (default options) where ``auto`` already ran it."""
        return self.selection.calibration if self.selection is not None else None


def choose_terms(kind: str, model: MeasurementModel, links: LinkMasses | None, unknowns: int) -> TermChoice:
    """The terms of ``--model kind`` on the training ``model`` (``unknowns``: what the table and
    setup alone leave to determine); ``auto`` cross-validates on these rows only."""
    offer = candidates(kind, model, links)
    every = [t for g in offer.groups for t in g.terms]
    if kind != "auto":
        return TermChoice(model.with_terms(offer.pool.subset(every)), None, offer.held)
    n = len(model.samples)
    per_fold = n - -(-n // FOLDS)
    if per_fold < unknowns + len(every):
        warning = TOO_FEW.format(n=n, per_fold=per_fold, needed=unknowns + len(every))
        return TermChoice(model, None, offer.held, warning)
    selection = select_terms(model, list(offer.groups), offer.pool, CalibrationOptions())
    kept = [t for g in selection.groups for t in g.terms]
    held = dict(offer.held)
    by_label = {g.label: g for g in offer.groups}
    base = {s.round: s.rmse_mm for s in selection.table if s.kept}
    for label, score in selection.rejected().items():
        reason = NOT_CHOSEN.format(
            rmse=score.rmse_mm, base=base[score.round - 1], change=-score.gain, need=selection.min_gain
        )
        held.update(dict.fromkeys((t.name for t in by_label[label].terms), reason))
    return TermChoice(model.with_terms(offer.pool.subset(kept)), selection, held)
