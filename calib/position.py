"""Position measurement model: TCP positions measured by an instrument (a laser tracker) in its frame.

Unknowns ``x = [dh (24), tracker rotation (3), tracker translation (3), probe (3), terms (K)]``:

- ``dh``: the D-H table, internal units (rad, mm);
- the base-to-tracker transform, minimal about a fixed reference ``(R0, t0)`` (a Kabsch fit of the
  nominal TCPs to the measured points)::

      tracker_from_base(w, t) = (exp([w]x) R0,  t0 + t),   w [rad] a rotation vector, t [mm];

- ``probe``: the measured point in the flange frame [mm];
- the robot's joint-space terms beyond the table (``calib.joint_terms``: compliance, harmonics).

Residuals, three per row, whitened: ``(tracker_from_base (p_TCP(q_link)) - m) / sigma``, with
``q_link`` the angles the links take.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from calib.calibrate import CalibrationOptions, robust_fit
from calib.identifiability import structural_holds, tolerance
from calib.joint_terms import JointTerms
from calib.kinematics import N_DH, base_from_frames, dh_table, tcp_position
from calib.lm import LMResult
from calib.metrics import rigid_fit
from calib.models import MeasurementAdvice
from calib.params import DH_NAMES

GROUP_POSITION = 0
TRACKER_NAMES = ("tracker.rot_x_deg", "tracker.rot_y_deg", "tracker.rot_z_deg")
TRACKER_NAMES += ("tracker.x_mm", "tracker.y_mm", "tracker.z_mm")
PROBE_NAMES = ("probe.x_mm", "probe.y_mm", "probe.z_mm")
N_SETUP = len(TRACKER_NAMES) + len(PROBE_NAMES)
ONE_ORIENTATION_DEG = 5.0
"""Poses whose tool axes all lie within this angle of one direction [deg] barely determine where
along that axis the probe sits (a shift along it is nearly a shift of the tracker)."""
ON_AXIS_MM = 1.0
"""A probe closer than this to joint 6's axis gives J5's tilt and turn a lever too short to see:
1 mrad moves it by less than 1 um."""


@dataclass(frozen=True)
class PositionSamples:
    """Position samples, one row per configuration.

    Attributes
    ----------
    q : ndarray, shape (N, 6)
        Joint readings [rad].
    position : ndarray, shape (N, 3)
        Measured positions [mm] in the instrument's frame.
    """

    q: np.ndarray
    position: np.ndarray

    def __len__(self) -> int:
        return self.q.shape[0]

    def subset(self, rows: np.ndarray) -> PositionSamples:
        """The samples of ``rows`` (indices or a boolean mask), in that order."""
        return PositionSamples(self.q[rows], self.position[rows])


@dataclass(frozen=True)
class Transform:
    """A rigid transform: ``rotation`` (3, 3) and ``translation_mm`` (3,) [mm]."""

    rotation: np.ndarray
    translation_mm: np.ndarray


@dataclass(frozen=True)
class TrackerSetupEstimate:
    """The tracker setup at a solution: ``tracker_from_base`` (the base frame's pose in the tracker
    frame) and ``probe_mm`` (3,) [mm], the measured point in the flange frame. Field names are the
    report's keys."""

    tracker_from_base: Transform
    probe_mm: np.ndarray


def rotation_from_vector(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, the rotation of a rotation vector.

    ``R = I + sin t / t [w]x + (1 - cos t) / t^2 [w]x^2``, ``t = |w|``, with the second-order series
    below ``t = 1e-6``.

    Parameters
    ----------
    w : ndarray, shape (3,)
        Rotation vector [rad]: axis times angle.

    Returns
    -------
    ndarray, shape (3, 3)
        ``exp([w]x)``.
    """
    theta = np.linalg.norm(w)
    k = _skew(w)
    if theta < 1e-6:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + np.sin(theta) / theta * k + (1 - np.cos(theta)) / theta**2 * k @ k


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3), for derivatives of a rotated vector by the rotation vector.

    ``d exp([w]x) v / dw = -[exp([w]x) v]x J_l(w)``, with
    ``J_l = I + (1 - cos t) / t^2 [w]x + (t - sin t) / t^3 [w]x^2``, ``t = |w|`` (series below 1e-6).

    Parameters
    ----------
    w : ndarray, shape (3,)
        Rotation vector [rad].

    Returns
    -------
    ndarray, shape (3, 3)
        ``J_l(w)``.
    """
    theta = np.linalg.norm(w)
    k = _skew(w)
    if theta < 1e-6:
        return np.eye(3) + 0.5 * k + k @ k / 6.0
    return np.eye(3) + (1 - np.cos(theta)) / theta**2 * k + (theta - np.sin(theta)) / theta**3 * k @ k


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class TrackerReference:
    """The reference base-to-tracker transform ``(rotation (3, 3), translation (3,) [mm])`` that the
    six transform unknowns move away from."""

    rotation: np.ndarray
    translation: np.ndarray

    @classmethod
    def kabsch(cls, samples: PositionSamples, dh: np.ndarray, probe: np.ndarray) -> TrackerReference:
        """Initial registration: the rigid fit of the modelled TCPs to the measured points.

        Parameters
        ----------
        samples : PositionSamples
            Joints and measured points.
        dh : ndarray, shape (6, 4)
            D-H table, internal units (rad, mm).
        probe : ndarray, shape (3,)
            Probe point in the flange frame [mm].

        Returns
        -------
        TrackerReference
        """
        rot, t = rigid_fit(tcp_position(dh, samples.q, probe), samples.position)
        return cls(rot, t)


class PositionModel:
    """Measured TCP positions in the tracker frame (see the module docstring).

    Parameters
    ----------
    samples : PositionSamples
        The N rows.
    dh0 : ndarray, shape (6, 4)
        Starting table, internal units (rad, mm).
    probe0 : ndarray, shape (3,)
        Starting probe offset in the flange frame [mm].
    reference : TrackerReference, optional
        The fixed base-to-tracker reference (default: Kabsch at ``dh0``, ``probe0``).
    sigma_mm : float
        Position noise per axis [mm].
    terms : JointTerms, optional
        Joint-space terms beyond the table (default: none).
    """

    kind: ClassVar[str] = "position"

    def __init__(
        self,
        samples: PositionSamples,
        dh0: np.ndarray,
        probe0: np.ndarray,
        reference: TrackerReference | None = None,
        sigma_mm: float = 0.05,
        terms: JointTerms | None = None,
    ):
        self.samples, self.sigma = samples, float(sigma_mm)
        self.dh0, self.probe0 = np.asarray(dh0, float), np.asarray(probe0, float)
        self.reference = reference or TrackerReference.kabsch(samples, self.dh0, self.probe0)
        self.terms = terms or JointTerms()
        self._basis = self.terms.basis(samples.q)
        self.names = DH_NAMES + TRACKER_NAMES + PROBE_NAMES + self.terms.names
        self.x0 = np.concatenate([self.dh0.ravel(), np.zeros(6), self.probe0, np.zeros(len(self.terms))])
        index = np.arange(len(self.names))
        self.setup_mask = (index >= N_DH) & (index < N_DH + N_SETUP)
        self.tool_mask = (index >= N_DH + 6) & (index < N_DH + N_SETUP)
        n = len(samples)
        self.rows = np.repeat(np.arange(n), 3)
        self.groups = np.full(3 * n, GROUP_POSITION)
        self.pose_groups = (GROUP_POSITION,)

    def prior_sigma(self) -> np.ndarray:
        """The table's manufacturing tolerance and the terms' priors; the tracker placement and
        probe are free."""
        sigma = np.full(len(self.names), np.inf)
        sigma[:N_DH] = tolerance(self.names[:N_DH])
        sigma[N_DH + N_SETUP :] = self.terms.prior_sigma()
        return sigma

    def gauges(self, x: np.ndarray | None = None) -> dict[str, str]:
        """Table parameters no position data can determine at ``x`` (default the start) with a free
        base-to-tracker transform and a free probe offset."""
        x = self.x0 if x is None else x
        held = structural_holds(self.dh(x), self.probe(x), "base-to-tracker transform")
        for col in ("theta_deg", "d_mm", "a_mm", "alpha_deg"):
            held[f"J6.{col}"] = (
                "probe gauge: it moves the probe point rigidly with the flange, which the free probe "
                "offset absorbs"
            )
        off_axis = self.probe_axis_distance_mm(x)
        if off_axis < ON_AXIS_MM:
            why = (
                f"the probe lies {off_axis:.2f} mm from joint 6's axis: turning that axis about {{}} "
                "moves the probe as {} does"
            )
            held["J5.theta_deg"] = why.format("joint 5's axis", "J5.a")
            held["J5.alpha_deg"] = why.format("its common normal with joint 5", "J5.d")
        return held

    def probe_axis_distance_mm(self, x: np.ndarray | None = None) -> float:
        """Distance of the probe point from joint 6's axis at ``x`` (default the start) [mm]."""
        x = self.x0 if x is None else x
        _, _, a6, alpha6 = self.dh(x)[5]
        px, py, pz = self.probe(x)
        return float(np.hypot(a6 + px, np.cos(alpha6) * py - np.sin(alpha6) * pz))

    def with_samples(self, samples: PositionSamples) -> PositionModel:
        """The same model (start, reference, noise, terms) on other rows measured from the same
        tracker placement, e.g. a hold-out set."""
        return PositionModel(samples, self.dh0, self.probe0, self.reference, self.sigma, self.terms)

    def with_terms(self, terms: JointTerms) -> PositionModel:
        """The same model (rows, start, reference, noise) with other joint-space terms."""
        return PositionModel(self.samples, self.dh0, self.probe0, self.reference, self.sigma, terms)

    def with_start(self, dh0: np.ndarray, probe0: np.ndarray) -> PositionModel:
        """The same rows started from another table and probe (new Kabsch reference)."""
        return PositionModel(self.samples, dh0, probe0, None, self.sigma, self.terms)

    # -- unpacking ---------------------------------------------------------------------------
    def dh(self, x: np.ndarray) -> np.ndarray:
        """The D-H table (6, 4) in ``x``, internal units."""
        return dh_table(x)

    def tracker_from_base(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation (3, 3) and translation (3,) [mm] of the base in the tracker frame."""
        rot = rotation_from_vector(x[N_DH : N_DH + 3]) @ self.reference.rotation
        return rot, self.reference.translation + x[N_DH + 3 : N_DH + 6]

    def probe(self, x: np.ndarray) -> np.ndarray:
        """The probe point (3,) [mm] in the flange frame."""
        return x[N_DH + 6 : N_DH + 9]

    def tcp_in_flange(self, x: np.ndarray) -> np.ndarray:
        """The TCP (3,) [mm] in the flange frame: the fitted probe point."""
        return self.probe(x)

    def term_values(self, x: np.ndarray) -> np.ndarray:
        """The joint-space terms' values (K,) in ``x``, internal units."""
        return x[N_DH + N_SETUP :]

    def setup_estimate(self, x: np.ndarray) -> TrackerSetupEstimate:
        """Base-to-tracker transform and probe at ``x`` (see ``TrackerSetupEstimate``)."""
        rot, t = self.tracker_from_base(x)
        return TrackerSetupEstimate(Transform(rot, t), self.probe(x))

    def joints(self, x: np.ndarray) -> np.ndarray:
        """Joint angles the links take [rad], (N, 6): readings plus the terms' deflections."""
        return self.terms.link_angles(self.samples.q, self.term_values(x), self._basis)

    # -- what the station asks ---------------------------------------------------------------
    def placement_ids(self) -> np.ndarray:
        """One tracker placement for every row: zeros (N,)."""
        return np.zeros(len(self.samples), int)

    def measurement_advice(self, x: np.ndarray) -> MeasurementAdvice:
        """More configurations, spread over the joints' ranges: a tracker sees every direction of
        the measured point, so what is missing is variety of poses; first of all of the tool's
        direction where it hardly turns (an ISO 9283 cube keeps one orientation), as then nothing
        tells where along its axis the probe sits."""
        axis = base_from_frames(self.dh(x), self.joints(x))[:, -1, :3, 2]
        mean = axis.mean(axis=0)
        spread = np.degrees(np.arccos(np.clip(axis @ (mean / np.linalg.norm(mean)), -1.0, 1.0))).max()
        advice = "measure more configurations, spread over every joint's range"
        if spread < ONE_ORIENTATION_DEG:
            advice = (
                f"turn the tool between poses (its axis stays within {spread:.1f} deg of one direction, "
                f"so where the probe sits along it is not determined); {advice}"
            )
        return MeasurementAdvice(f"its {len(self.samples)} poses", advice)

    # -- residuals ---------------------------------------------------------------------------
    def predicted_mm(self, x: np.ndarray) -> np.ndarray:
        """Model positions in the tracker frame [mm], (N, 3)."""
        rot, t = self.tracker_from_base(x)
        return tcp_position(self.dh(x), self.joints(x), self.probe(x)) @ rot.T + t

    def row_error_mm(self, x: np.ndarray) -> np.ndarray:
        """Distance between measured and model position, ``|m - p_model|`` (the contract's metric).

        Parameters
        ----------
        x : ndarray, shape (n,)
            Full parameter vector, internal units.

        Returns
        -------
        ndarray, shape (N,)
            Distances [mm].
        """
        return np.linalg.norm(self.samples.position - self.predicted_mm(x), axis=1)

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Whitened residuals (3N,): per row the x, y, z position error over ``sigma``."""
        return self._evaluate(x, jacobian=False)[0]

    def row_residuals(self, x: np.ndarray) -> np.ndarray:
        """Each row's whitened x, y, z position error (N, 3)."""
        return self.residuals(x).reshape(len(self.samples), 3)

    def holding_robot(self) -> PositionModel:
        """This model itself: the tracker's and the probe's columns need the kinematics anyway."""
        return self

    def by_axes(self) -> PositionModel:
        """This model itself: its kinematics stay the row-by-row products (needs their rotations)."""
        return self

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True):
        """Whitened residuals (3N,) and their analytic Jacobian (3N, n), None unless ``jacobian``."""
        return self._evaluate(x, jacobian)

    def _evaluate(self, x, jacobian):
        rot, t = self.tracker_from_base(x)
        dh, q, probe = self.dh(x), self.joints(x), self.probe(x)
        if not jacobian:
            p = tcp_position(dh, q, probe)
            return ((p @ rot.T + t - self.samples.position) / self.sigma).ravel(), None
        p, dp, dp_terms = self.terms.tcp_jacobian(dh, self.samples.q, probe, self.term_values(x), self._basis)
        rp = p @ rot.T
        r = (rp + t - self.samples.position) / self.sigma
        n = len(self.samples)
        j = np.zeros((n, 3, x.size))
        j[:, :, :N_DH] = np.einsum("ij,njk->nik", rot, dp)
        w = x[N_DH : N_DH + 3]
        j[:, :, N_DH : N_DH + 3] = -np.einsum("nij,jk->nik", _skew_batch(rp), left_jacobian(w))
        j[:, :, N_DH + 3 : N_DH + 6] = np.eye(3)
        flange_rot = base_from_frames(dh, q)[:, 6, :3, :3]
        j[:, :, N_DH + 6 : N_DH + 9] = np.einsum("ij,njk->nik", rot, flange_rot)
        j[:, :, N_DH + N_SETUP :] = np.einsum("ij,njk->nik", rot, dp_terms)
        return r.ravel(), j.reshape(3 * n, x.size) / self.sigma


def _skew_batch(v: np.ndarray) -> np.ndarray:
    """Skew matrices of vectors (N, 3) -> (N, 3, 3)."""
    out = np.zeros(v.shape[:1] + (3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def register(
    model: PositionModel,
    dh: np.ndarray,
    term_values: np.ndarray | None = None,
    options: CalibrationOptions | None = None,
) -> tuple[PositionModel, LMResult]:
    """Fit a series' base-to-tracker transform and probe offset with the robot held.

    Parameters
    ----------
    model : PositionModel
        The series' rows (its probe start and terms are kept).
    dh : ndarray, shape (6, 4)
        The table to hold, internal units (rad, mm).
    term_values : ndarray, shape (K,), optional
        The model's joint-space terms' values to hold, internal units (default: 0).
    options : CalibrationOptions, optional
        Loss and solver options.

    Returns
    -------
    model : PositionModel
        The model started at ``dh``, with its own Kabsch reference.
    result : LMResult
        The fit; ``model.row_error_mm(result.x)`` are the registered errors [mm].
    """
    started = model.with_start(dh, model.probe0)
    x0 = started.x0.copy()
    if term_values is not None:
        x0[N_DH + N_SETUP :] = term_values
    result, _ = robust_fit(started, x0, started.setup_mask, options or CalibrationOptions())
    return started, result
