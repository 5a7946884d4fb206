"""The running calibration's work: the whole calibration pipeline on the samples a session has so
far, and what its result predicts for the next reading.

A refit is the service's pipeline (setup priors, identification, LMLC, covariance, predicted
workspace error) on the first ``n`` samples, with two rules for a session still growing:

- a gauge line joins the line constraint once ``MIN_LINE_SAMPLES`` samples are on it (a line
  fitted through one or two points is no line); until then its samples count as drawstring rows;
- while the samples cannot determine the unknowns (fewer than ``station calibrate`` accepts), the
  fit uses the linear loss (a robust scale fitted to fewer residuals than unknowns is no scale: the
  fit leaves them near zero) and promises nothing (``judged`` is False): no workspace accuracy
  (with so few samples the pipeline identifies table parameters the data barely constrains, and
  the consider analysis rightly predicts tens of millimetres) and no uncertainty of a prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.calibrate import CalibrationOptions, calibrate
from calib.models import MeasurementModel
from station.formats.samples import Samples
from station.formats.tables import RobotFile, SetupFile
from station.jobs.calibration import build_model, model_samples, predicted_workspace, unknowns
from station.jobs.report import WorkspacePrediction

MIN_LINE_SAMPLES = 3


@dataclass(frozen=True)
class SessionSamples:
    """A session's samples so far: joints (N, 6) [deg], drawstring (N,) [mm], dial (N,) [mm, NaN:
    none] and gauge line ids (N,)."""

    q_deg: np.ndarray
    length_mm: np.ndarray
    dial_mm: np.ndarray
    line: np.ndarray

    def __len__(self) -> int:
        return len(self.length_mm)

    def as_samples(self, where: str) -> Samples:
        """As the calibration service takes them, lines with too few samples unconstrained."""
        line = self.line.copy()
        ids, counts = np.unique(line[line >= 0], return_counts=True)
        line[np.isin(line, ids[counts < MIN_LINE_SAMPLES])] = -1
        return Samples(where, "drawstring", self.q_deg, self.length_mm, self.dial_mm, line)


@dataclass(frozen=True)
class Refit:
    """One refit on the first ``n`` samples: the ``model`` and solution ``x`` (internal units), the
    ``covariance`` of the ``free`` unknowns, the drawstring's noise ``noise_mm`` per sample (robust
    spread of its residuals), the predicted ``workspace`` error (None while the samples cannot
    determine the ``needed`` unknowns: then neither the covariance nor the noise mean anything), what
    the model advises to measure next, and the plan's ``targets`` corrected for this model (a
    ``station.jobs.correction.TargetCorrection``, where the session's worker was asked for them)."""

    n: int
    model: MeasurementModel
    x: np.ndarray
    covariance: np.ndarray
    free: np.ndarray
    noise_mm: float
    workspace: WorkspacePrediction | None
    needed: int
    advice: str
    targets: object = None

    @property
    def judged(self) -> bool:
        """Whether the samples determine the unknowns: a prediction's uncertainty means something."""
        return self.workspace is not None

    def predict(self, q_deg, sigma_mm: float) -> tuple[float, float]:
        """The drawstring length this model predicts at joints ``q_deg`` (6,) [deg] and its standard
        deviation [mm] from the covariance; ``sigma_mm`` is the setup's stated drawstring noise
        that the model's residuals are divided by (contract)."""
        row = SessionSamples(np.atleast_2d(q_deg), np.zeros(1), np.full(1, np.nan), np.full(1, -1))
        one = self.model.with_samples(model_samples(row.as_samples("prediction")))
        _, jac = one.residuals_and_jacobian(self.x)
        model_mm = -float(one.row_error_mm(self.x)[0])  # reading 0: the error is minus the model
        gradient = sigma_mm * jac[0, self.free]  # the first residual is (model - reading) / sigma
        return model_mm, float(np.sqrt(max(gradient @ self.covariance @ gradient, 0.0)))


def refit(robot: RobotFile, setup: SetupFile, samples: SessionSamples) -> Refit:
    """The pipeline on ``samples`` (see the module notes)."""
    model = build_model(samples.as_samples("session"), robot, setup, "setup")
    needed = unknowns(model)
    enough = len(samples) >= needed
    cal = calibrate(model, CalibrationOptions() if enough else CalibrationOptions(loss="linear"))
    return Refit(
        n=len(samples),
        model=model,
        x=cal.x,
        covariance=cal.covariance,
        free=cal.identified,
        noise_mm=1.4826 * float(np.median(np.abs(model.row_error_mm(cal.x)))),
        workspace=predicted_workspace(robot, cal, model) if enough else None,
        needed=needed,
        advice=model.measurement_advice(cal.x).next_measurement,
    )
