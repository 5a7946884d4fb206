"""Position measurement model: TCP positions measured by an instrument (a laser tracker) in its frame.

Unknowns ``x = [dh (24), tracker rotation (3), tracker translation (3), probe (3), compliance (k)]``:

- ``dh``: the D-H table, internal units (rad, mm);
- the base-to-tracker transform, minimal about a fixed reference ``(R0, t0)`` (a Kabsch fit of the
  nominal TCPs to the measured points)::

      tracker_from_base(w, t) = (exp([w]x) R0,  t0 + t),   w [rad] a rotation vector, t [mm];

- ``probe``: the measured point in the flange frame [mm];
- optionally one compliance per chosen joint [urad / (N m)]: the joint turns by ``c_j tau_j`` under
  the gravity torque ``tau_j(q)`` of the links beyond it (computed once from the starting table).

Residuals, three per row, whitened: ``(tracker_from_base (p_TCP(q + 1e-6 c tau)) - m) / sigma``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from calib.calibrate import CalibrationOptions, robust_fit
from calib.identifiability import structural_holds, tolerance
from calib.kinematics import N_DH, THETA, base_from_frames, dh_table, tcp_jacobian, tcp_position
from calib.lm import LMResult
from calib.metrics import rigid_fit
from calib.params import DH_NAMES

GROUP_POSITION = 0
TRACKER_NAMES = ("tracker.rot_x_deg", "tracker.rot_y_deg", "tracker.rot_z_deg")
TRACKER_NAMES += ("tracker.x_mm", "tracker.y_mm", "tracker.z_mm")
PROBE_NAMES = ("probe.x_mm", "probe.y_mm", "probe.z_mm")
MICRO = 1e-6  # compliance unknowns are in urad / (N m)
G_MS2 = 9.80665
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


@dataclass(frozen=True)
class LinkMasses:
    """Rigid-body masses for the gravity torques.

    Attributes
    ----------
    mass_kg : ndarray, shape (6,)
        Mass of each link [kg].
    com_mm : ndarray, shape (6, 3)
        Centre of mass of link i in D-H frame i [mm].
    gravity : tuple of 3 float
        Unit direction of gravity in the base frame.
    """

    mass_kg: np.ndarray
    com_mm: np.ndarray
    gravity: tuple[float, float, float] = (0.0, 0.0, -1.0)


@dataclass(frozen=True)
class Compliance:
    """Joints (0-based) that yield under gravity and the link masses that load them."""

    joints: tuple[int, ...]
    links: LinkMasses


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


def gravity_torques(dh: np.ndarray, q: np.ndarray, links: LinkMasses, joints) -> np.ndarray:
    """Gravity torque about each joint of ``joints`` from the links beyond it.

    ``tau_j = z_j . sum_{k >= j} (c_k - o_j) x (m_k g)``, with ``c_k`` the centre of mass of link k
    and ``z_j, o_j`` the axis and origin of D-H frame j.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        D-H table, internal units (rad, mm).
    q : ndarray, shape (N, 6)
        Joint angles [rad].
    links : LinkMasses
        Masses [kg] and centres of mass [mm].
    joints : sequence of int
        0-based joints.

    Returns
    -------
    ndarray, shape (N, len(joints))
        Torques [N m].
    """
    frames = base_from_frames(dh, q)
    com = np.einsum("nkij,kj->nki", frames[:, 1:, :3, :3], links.com_mm) + frames[:, 1:, :3, 3]
    force = links.mass_kg[:, None] * G_MS2 * np.asarray(links.gravity, float)  # (6, 3) [N]
    out = np.empty((q.shape[0], len(joints)))
    for c, j in enumerate(joints):
        z, o = frames[:, j, :3, 2], frames[:, j, :3, 3]
        moment = np.cross(com[:, j:] - o[:, None, :], force[None, j:]).sum(axis=1)  # [N mm]
        out[:, c] = np.einsum("ni,ni->n", z, moment) * 1e-3
    return out


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
    compliance : Compliance, optional
        Joints that yield under gravity; None for a purely geometric model.
    """

    kind: ClassVar[str] = "position"

    def __init__(
        self,
        samples: PositionSamples,
        dh0: np.ndarray,
        probe0: np.ndarray,
        reference: TrackerReference | None = None,
        sigma_mm: float = 0.05,
        compliance: Compliance | None = None,
    ):
        self.samples, self.sigma = samples, float(sigma_mm)
        self.dh0, self.probe0 = np.asarray(dh0, float), np.asarray(probe0, float)
        self.reference = reference or TrackerReference.kabsch(samples, self.dh0, self.probe0)
        self.compliance = compliance
        joints = compliance.joints if compliance else ()
        self.torques = gravity_torques(self.dh0, samples.q, compliance.links, joints) if compliance else None
        comp_names = tuple(f"J{j + 1}.compliance_urad_per_Nm" for j in joints)
        self.names = DH_NAMES + TRACKER_NAMES + PROBE_NAMES + comp_names
        self.x0 = np.concatenate([self.dh0.ravel(), np.zeros(6), self.probe0, np.zeros(len(joints))])
        self.setup_mask = np.arange(len(self.names)) >= N_DH  # everything but the table (solver's view)
        n = len(samples)
        self.rows = np.repeat(np.arange(n), 3)
        self.groups = np.full(3 * n, GROUP_POSITION)

    def prior_sigma(self) -> np.ndarray:
        """The table's manufacturing tolerance; the tracker placement and probe are free."""
        sigma = np.full(len(self.names), np.inf)
        sigma[:N_DH] = tolerance(self.names[:N_DH])
        return sigma

    def gauges(self) -> dict[str, str]:
        """Table parameters no position data can determine with a free base-to-tracker transform and
        a free probe offset."""
        held = structural_holds(self.dh0, self.probe0, "base-to-tracker transform")
        for col in ("theta_deg", "d_mm", "a_mm", "alpha_deg"):
            held[f"J6.{col}"] = (
                "probe gauge: it moves the probe point rigidly with the flange, which the free probe "
                "offset absorbs"
            )
        off_axis = self.probe_axis_distance_mm()
        if off_axis < ON_AXIS_MM:
            why = (
                f"the probe lies {off_axis:.2f} mm from joint 6's axis: turning that axis about {{}} "
                "moves the probe as {} does"
            )
            held["J5.theta_deg"] = why.format("joint 5's axis", "J5.a")
            held["J5.alpha_deg"] = why.format("its common normal with joint 5", "J5.d")
        return held

    def probe_axis_distance_mm(self) -> float:
        """Distance of the starting probe point from joint 6's axis [mm]."""
        _, _, a6, alpha6 = self.dh0[5]
        px, py, pz = self.probe0
        return float(np.hypot(a6 + px, np.cos(alpha6) * py - np.sin(alpha6) * pz))

    def with_samples(self, samples: PositionSamples) -> PositionModel:
        """The same model (start, reference, noise, compliance) on other rows measured from the same
        tracker placement, e.g. a hold-out set."""
        return PositionModel(samples, self.dh0, self.probe0, self.reference, self.sigma, self.compliance)

    def with_start(self, dh0: np.ndarray, probe0: np.ndarray) -> PositionModel:
        """The same rows started from another table and probe (new Kabsch reference)."""
        return PositionModel(self.samples, dh0, probe0, None, self.sigma, self.compliance)

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

    def setup_estimate(self, x: np.ndarray) -> TrackerSetupEstimate:
        """Base-to-tracker transform and probe at ``x`` (see ``TrackerSetupEstimate``)."""
        rot, t = self.tracker_from_base(x)
        return TrackerSetupEstimate(Transform(rot, t), self.probe(x))

    def joints(self, x: np.ndarray) -> np.ndarray:
        """Joint angles the links take [rad]: readings plus the gravity deflection, (N, 6)."""
        q = self.samples.q.copy()
        if self.compliance is not None:
            q[:, list(self.compliance.joints)] += MICRO * self.torques * x[N_DH + 9 :]
        return q

    # -- what the station asks ---------------------------------------------------------------
    def placement_ids(self) -> np.ndarray:
        """One tracker placement for every row: zeros (N,)."""
        return np.zeros(len(self.samples), int)

    def measurement_advice(self, x: np.ndarray) -> None:
        """No advice: a position set's predicted workspace error keeps a floor from the held
        parameters considered at their tolerance (J6's, which the free probe offset absorbs: about
        1.5 mm on a UR10) that no further pose lowers, so "fits well, predicts badly" holds for
        every good tracker set and says nothing about what to measure."""
        return None

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

    def residuals_and_jacobian(self, x: np.ndarray, jacobian: bool = True):
        """Whitened residuals (3N,) and their analytic Jacobian (3N, n), None unless ``jacobian``."""
        return self._evaluate(x, jacobian)

    def _evaluate(self, x, jacobian):
        rot, t = self.tracker_from_base(x)
        dh, q, probe = self.dh(x), self.joints(x), self.probe(x)
        if not jacobian:
            p = tcp_position(dh, q, probe)
            return ((p @ rot.T + t - self.samples.position) / self.sigma).ravel(), None
        p, dp = tcp_jacobian(dh, q, probe)
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
        if self.compliance is not None:
            dq = j[:, :, [THETA + 4 * k for k in self.compliance.joints]]  # dp/dq_j = dp/dtheta_j
            j[:, :, N_DH + 9 :] = dq * (MICRO * self.torques[:, None, :])
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
    compliance: np.ndarray | None = None,
    options: CalibrationOptions | None = None,
) -> tuple[PositionModel, LMResult]:
    """Fit a series' base-to-tracker transform and probe offset with the table held.

    Parameters
    ----------
    model : PositionModel
        The series' rows (its probe start and compliance joints are kept).
    dh : ndarray, shape (6, 4)
        The table to hold, internal units (rad, mm).
    compliance : ndarray, shape (k,), optional
        Joint compliances [urad / (N m)] to hold, if the model has that term.
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
    if compliance is not None:
        x0[N_DH + 9 :] = compliance
    free = np.zeros(len(started.names), bool)
    free[N_DH : N_DH + 9] = True  # transform and probe only: the compliances are the robot's
    result, _ = robust_fit(started, x0, free, options or CalibrationOptions())
    return started, result
