"""Joint-space terms beyond the D-H geometry: the angles the links really take.

A joint reading ``q_j`` is not quite the angle its link turns by: the joint yields under the gravity
torque of the links beyond it, and the encoder and the transmission add errors that repeat with the
joint's angle. Both are linear in the terms' values ``c`` (K of them)::

    q_link_j = q_j + sum_{k: joint_k = j} B_k(q) c_k,

with the basis ``B`` (N, K) of each term kind (``TERM_KINDS``, the key a robot file and the report
use after ``J<j>.``):

- ``compliance_urad_per_Nm``: ``B = 1e-6 tau_j(q)``, ``tau_j`` the gravity torque [N m] of the links
  beyond joint j and a payload (``gravity_torques``), computed once from the starting table;
- ``sin1_deg``, ``cos1_deg``, ``sin2_deg``, ``cos2_deg``: ``B = sin(q_j)``, ``cos(q_j)``,
  ``sin(2 q_j)``, ``cos(2 q_j)``, values in rad inside the maths (deg shown).

Since a D-H joint turns by ``theta_j + q_j``, the TCP's derivative by a term is its joint's theta
column times the basis: ``dp / dc_k = dp / dtheta_{joint_k} B_k(q)``. Both measurement models use
this one implementation (``JointTerms.tcp_jacobian``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import N_JOINTS, THETA, base_from_frames, tcp_jacobian, tcp_jacobian_by_axes

G_MS2 = 9.80665
MICRO = 1e-6  # compliances are in urad / (N m)
COMPLIANCE = "compliance_urad_per_Nm"
HARMONICS = {1: ("sin1_deg", "cos1_deg"), 2: ("sin2_deg", "cos2_deg")}
WAVE = {"sin1_deg": (np.sin, 1), "cos1_deg": (np.cos, 1), "sin2_deg": (np.sin, 2), "cos2_deg": (np.cos, 2)}
"""Each harmonic's function and order: its basis is ``fun(order * q_j)``."""
TERM_KINDS = (COMPLIANCE,) + HARMONICS[1] + HARMONICS[2]
"""Term keys, as a robot file's joint and the report (``J2.compliance_urad_per_Nm``) name them."""

COMPLIANCE_PRIOR = 30.0
"""What is known of a joint's compliance before measuring [urad / (N m)], 1 sigma: a joint
stiffness above about 3e4 N m/rad (industrial joints: 3e4 - 1e6)."""
HARMONIC_PRIOR_DEG = 0.05
"""What is known of a harmonic's amplitude before measuring [deg], 1 sigma: about 3 arc minutes,
the size of a strain-wave gear's transmission error."""
TURN_GAP_DEG = 90.0
"""A joint's rows cover its whole turn when the largest arc of its angle (mod 360 deg) that no row
visits is under this (a quarter turn): a first harmonic fitted there interpolates at every angle."""
LOAD_BEARING_SHARE = 0.1
"""A joint carries the arm when the RMS of its gravity torque over the rows is at least this share
of the largest joint's: those joints get a compliance candidate."""


@dataclass(frozen=True)
class LinkMasses:
    """Rigid-body masses for the gravity torques.

    Attributes
    ----------
    mass_kg : ndarray, shape (6,)
        Mass of each link [kg] (link 6 with whatever it carries).
    com_mm : ndarray, shape (6, 3)
        Centre of mass of link i in D-H frame i [mm].
    gravity : tuple of 3 float
        Unit direction of gravity in the base frame.
    """

    mass_kg: np.ndarray
    com_mm: np.ndarray
    gravity: tuple[float, float, float] = (0.0, 0.0, -1.0)

    def with_payload(self, mass_kg: float, com_mm) -> LinkMasses:
        """The same arm carrying a payload of ``mass_kg`` [kg] whose centre is ``com_mm`` (3,) [mm]
        in the flange frame (D-H frame 6): lumped into link 6."""
        mass, com = self.mass_kg.copy(), self.com_mm.copy()
        total = mass[-1] + mass_kg
        if total > 0:
            com[-1] = (mass[-1] * com[-1] + mass_kg * np.asarray(com_mm, float)) / total
        mass[-1] = total
        return LinkMasses(mass, com, self.gravity)


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
class Term:
    """One joint-space term: its 0-based ``joint`` and its ``key`` (one of ``TERM_KINDS``)."""

    joint: int
    key: str

    @property
    def name(self) -> str:
        """The report's name, e.g. ``J2.compliance_urad_per_Nm``."""
        return f"J{self.joint + 1}.{self.key}"


@dataclass(frozen=True)
class TermGroup:
    """Terms that enter or leave a model together (a harmonic's sine and cosine), with a label."""

    label: str
    terms: tuple[Term, ...]


def compliance_group(joint: int) -> TermGroup:
    """Joint ``joint`` (0-based) yielding under gravity."""
    return TermGroup(f"J{joint + 1} compliance", (Term(joint, COMPLIANCE),))


def harmonic_group(joint: int, order: int) -> TermGroup:
    """The ``order``-th harmonic (1 or 2) of joint ``joint``'s (0-based) angle, sine and cosine."""
    return TermGroup(f"J{joint + 1} harmonic {order}", tuple(Term(joint, k) for k in HARMONICS[order]))


def load_bearing_joints(dh: np.ndarray, q: np.ndarray, links: LinkMasses) -> tuple[int, ...]:
    """Joints (0-based) whose gravity torque over the configurations ``q`` (N, 6) [rad] has an RMS
    of at least ``LOAD_BEARING_SHARE`` of the largest joint's: those that carry the arm."""
    rms = np.sqrt(np.mean(gravity_torques(dh, q, links, range(N_JOINTS)) ** 2, axis=0))
    return tuple(int(j) for j in np.flatnonzero(rms >= LOAD_BEARING_SHARE * rms.max()))


def turn_gap(q: np.ndarray) -> np.ndarray:
    """The largest arc [rad] of each joint's circle (6,) that none of the configurations ``q``
    (N, 6) [rad] visits."""
    angles = np.sort(np.mod(q, 2.0 * np.pi), axis=0)
    wrapped = np.vstack([angles, angles[:1] + 2.0 * np.pi])
    return np.max(np.diff(wrapped, axis=0), axis=0)


def whole_turn_joints(q: np.ndarray) -> tuple[int, ...]:
    """Joints (0-based) whose angles over ``q`` (N, 6) [rad] cover the whole turn: no unvisited arc
    (``turn_gap``) as wide as ``TURN_GAP_DEG``. An encoder's scale mounted off its axis reads a
    once-per-turn error (the first harmonic), which such rows determine everywhere and partial turns
    only extrapolate."""
    return tuple(int(j) for j in np.flatnonzero(turn_gap(q) < np.radians(TURN_GAP_DEG)))


class JointTerms:
    """A set of joint-space terms and what their basis needs (module docstring).

    Parameters
    ----------
    terms : sequence of Term
        The terms, in the order of their values ``c``.
    dh : ndarray, shape (6, 4)
        The table the gravity torques are computed with (the starting table), internal units.
    links : LinkMasses, optional
        Masses and centres of mass; required when a term is a compliance.
    """

    def __init__(self, terms=(), dh: np.ndarray | None = None, links: LinkMasses | None = None):
        self.terms = tuple(terms)
        if any(t.key == COMPLIANCE for t in self.terms) and (links is None or dh is None):
            raise ValueError("a compliance term needs the link masses and a table")
        unknown = [t.key for t in self.terms if t.key not in TERM_KINDS]
        if unknown:
            raise ValueError(f"unknown term kind {unknown[0]!r}: one of {', '.join(TERM_KINDS)}")
        self.dh, self.links = dh, links
        self.names = tuple(t.name for t in self.terms)
        self.joints = np.array([t.joint for t in self.terms], int)

    def __len__(self) -> int:
        return len(self.terms)

    def subset(self, terms) -> JointTerms:
        """Other terms with the same table and masses."""
        return JointTerms(terms, self.dh, self.links)

    def prior_sigma(self) -> np.ndarray:
        """What is known of each term before measuring (1 sigma, internal units), shape (K,)."""
        return np.array(
            [COMPLIANCE_PRIOR if t.key == COMPLIANCE else np.radians(HARMONIC_PRIOR_DEG) for t in self.terms]
        )

    def basis(self, q: np.ndarray) -> np.ndarray:
        """Each term's joint deflection per unit value at configurations ``q``.

        Parameters
        ----------
        q : ndarray, shape (N, 6)
            Joint readings [rad].

        Returns
        -------
        ndarray, shape (N, K)
            rad per internal unit (urad / (N m) for a compliance, rad for a harmonic).
        """
        out = np.empty((q.shape[0], len(self.terms)))
        compliant = [k for k, t in enumerate(self.terms) if t.key == COMPLIANCE]
        if compliant:
            joints = self.joints[compliant]
            out[:, compliant] = MICRO * gravity_torques(self.dh, q, self.links, joints)
        for k, t in enumerate(self.terms):
            if t.key in WAVE:
                fun, order = WAVE[t.key]
                out[:, k] = fun(order * q[:, t.joint])
        return out

    def link_angles(self, q: np.ndarray, c: np.ndarray, basis: np.ndarray) -> np.ndarray:
        """The angles the links take [rad], (N, 6): readings ``q`` (N, 6) plus each term's
        ``basis`` (N, K) column times its value ``c`` (K,) on its joint."""
        out = np.array(q, float, copy=True)
        np.add.at(out.T, self.joints, (basis * c).T)
        return out

    def tcp_jacobian(
        self, dh: np.ndarray, q: np.ndarray, tool: np.ndarray, c: np.ndarray, basis: np.ndarray, by_axes=False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """TCP positions and their derivatives by the table and by the terms.

        Parameters
        ----------
        dh : ndarray, shape (6, 4)
            D-H table, internal units.
        q : ndarray, shape (N, 6)
            Joint readings [rad].
        tool : ndarray, shape (3,)
            TCP in the flange frame [mm].
        c : ndarray, shape (K,)
            Term values, internal units.
        basis : ndarray, shape (N, K)
            ``self.basis(q)`` (computed once per row set).
        by_axes : bool
            Compose the frames by ``kinematics.tcp_jacobian_by_axes`` (a fit's many rows), not by
            ``kinematics.tcp_jacobian``'s products.

        Returns
        -------
        p : ndarray, shape (N, 3)
            TCP positions [mm] at the link angles.
        jac_table : ndarray, shape (N, 3, 24)
            ``dp / d dh.ravel()``.
        jac_terms : ndarray, shape (N, 3, K)
            ``dp / dc``.
        """
        p, jac = (tcp_jacobian_by_axes if by_axes else tcp_jacobian)(dh, self.link_angles(q, c, basis), tool)
        return p, jac, jac[:, :, THETA + 4 * self.joints] * basis[:, None, :]

    def tcp_derivatives(
        self, dh: np.ndarray, q: np.ndarray, tool: np.ndarray, c: np.ndarray, basis: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``tcp_jacobian(..., by_axes=True)``'s TCPs (N, 3) [mm] and derivatives by the table, then
        by the terms, coordinate-major (3, N, 24 + K), written in place: the same numbers without
        a second copy of them (a million rows' are some 600 MB)."""
        dp = np.empty((3, q.shape[0], dh.size + len(self.terms)))
        p, _ = tcp_jacobian_by_axes(dh, self.link_angles(q, c, basis), tool, out=dp)
        np.multiply(dp[:, :, THETA + 4 * self.joints], basis, out=dp[:, :, dh.size :])
        return p, dp
