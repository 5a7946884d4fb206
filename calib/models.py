"""Measurement models: what the solver minimises, without the solver looking inside.

A model owns its data and maps a full parameter vector ``x`` to whitened residuals (each divided by
its noise) and their Jacobian. Everything the solver, the analyses around it and the station need
is a member of the model (``MeasurementModel``), so nothing outside ``calib`` asks which kind of
model it holds. The models: the drawstring + line model (``calib.drawstring``) and the laser
tracker's position model (``calib.position``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from calib.joint_terms import JointTerms

GROUP_LENGTH, GROUP_LINE_DIAL, GROUP_LINE_ACROSS, GROUP_PRIOR = 0, 1, 2, 3
"""Residual groups, each with its own fitted noise scale: the drawstring; a line contact along the
dial's axis (dial noise) and across it (only the arm's own noise); prior rows."""


@dataclass(frozen=True)
class MeasurementAdvice:
    """What to say when the rows fit well but cannot promise the workspace: what they ``cover``
    (the object of "fits ... to 0.02 mm") and the ``next_measurement`` that would help."""

    cover: str
    next_measurement: str


class SampleRows(Protocol):
    """A model's sample set: one row per robot configuration."""

    def __len__(self) -> int: ...

    def subset(self, rows: np.ndarray) -> SampleRows: ...


def spread_rows(n: int, k: int) -> np.ndarray:
    """``k`` of ``n`` row indices (ascending), a fixed draw spread over all of them: a thinned set
    that every k-th row would not alias with a session's repeated poses."""
    return np.sort(np.random.default_rng(0).choice(n, k, replace=False))


def thinned(model: MeasurementModel, k: int) -> MeasurementModel:
    """``model`` on ``k`` of its sample rows (``spread_rows``), itself if it has no more."""
    n = len(model.samples)
    return model if n <= k else model.with_samples(model.samples.subset(spread_rows(n, k)))


class MeasurementModel(Protocol):
    """What every measurement model provides.

    Attributes
    ----------
    kind : str
        The kind of measurement, as the report names it: ``"drawstring"`` or ``"position"``.
    samples : SampleRows
        The N sample rows the model was built on.
    names : tuple of str
        One name per entry of ``x``: the D-H table first (``calib.params.DH_NAMES``), then the setup
        unknowns, then the joint-space terms (``terms.names``).
    x0 : ndarray, shape (n,)
        The starting vector, internal units (rad, mm); the terms start at 0.
    setup_mask : ndarray of bool, shape (n,)
        The setup unknowns: everything that is not the robot's (table and terms).
    tool_mask : ndarray of bool, shape (n,)
        The setup unknowns that are the TCP's coordinates in the flange frame (a tracker's probe);
        none where the TCP is given.
    terms : JointTerms
        The robot's joint-space terms beyond the table (``calib.joint_terms``; empty: geometry only).
    groups : ndarray of int, shape (m,)
        Per residual, the instrument it comes from (robust scales are estimated per group).
    rows : ndarray of int, shape (m,)
        Per residual, the 0-based sample row it belongs to.
    pose_groups : tuple of int
        The residual groups whose rows are poses of their own, where an error that neighbouring
        poses share is weighed (``calib.discrepancy``); none where the rows trace gauge lines (one
        path, whose shared error its line's own unknowns take).
    """

    kind: str
    samples: SampleRows
    names: tuple[str, ...]
    x0: np.ndarray
    setup_mask: np.ndarray
    tool_mask: np.ndarray
    terms: JointTerms
    groups: np.ndarray
    rows: np.ndarray
    pose_groups: tuple[int, ...]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Whitened residuals, shape (m,), at ``x`` (n,)."""
        ...

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True) -> tuple:
        """Whitened residuals (m,) and their Jacobian (m, n) at ``x`` (None unless ``jacobian``)."""
        ...

    def gauges(self, x: np.ndarray | None = None) -> dict[str, str]:
        """Parameters that no data of this kind can determine at ``x`` (n,; default the start
        ``x0``), with the reason."""
        ...

    def holding_robot(self) -> MeasurementModel:
        """The same model for a fit that holds the robot (table and terms): its Jacobian's robot
        columns may be left zero (they are not fitted), the rest as the model's."""
        ...

    def by_axes(self) -> MeasurementModel:
        """The same model with its TCPs composed by ``kinematics.frame_axes`` (a calibration's fits:
        faster on many rows, other last digits than the row-by-row products planning keeps)."""
        ...

    def prior_sigma(self) -> np.ndarray:
        """What is known of each unknown before measuring (1 sigma, internal units; inf: nothing)."""
        ...

    def with_samples(self, samples) -> MeasurementModel:
        """The same model (start, frame, noise, terms) on other rows: a subset or a hold-out set."""
        ...

    def with_terms(self, terms: JointTerms) -> MeasurementModel:
        """The same model (rows, start, frame, noise) with other joint-space terms."""
        ...

    def row_error_mm(self, x: np.ndarray) -> np.ndarray:
        """The contract's error of each sample row [mm], shape (N,), at ``x``."""
        ...

    def row_residuals(self, x: np.ndarray) -> np.ndarray:
        """Each sample row's signed residual (N, k) at ``x``, whitened by its stated noise."""
        ...

    def tcp_in_flange(self, x: np.ndarray) -> np.ndarray:
        """The TCP (3,) [mm] in the flange frame at ``x``: the measured point."""
        ...

    def setup_estimate(self, x: np.ndarray):
        """The setup unknowns at ``x`` in display units, as a small dataclass whose field names are
        the report's keys."""
        ...

    def placement_ids(self) -> np.ndarray:
        """Per sample row (N,), the instrument placement it was measured at; a selection of
        configurations keeps some rows of every placement."""
        ...

    def measurement_advice(self, x: np.ndarray) -> MeasurementAdvice:
        """What the rows cover, and what to measure next when they fit well but cannot promise the
        workspace."""
        ...
