"""A robot's smooth error that no table (nor a compliance or a low harmonic) expresses, as the real
UR10 shows (``benchmarks/IPA_UR10.md``): the truth the residual map (``calib.residual_map``) is
tested against.

- a **cyclic error** of a joint, many cycles a turn (a gear's or strain wave's tooth-mesh error):
  the link turns by ``amplitude sin(cycles q + phase)`` more than the joint reads;
- a **sag** that grows with the reach: the TCP drops by ``sag_mm_per_m2`` times the square of its
  distance from joint 1's axis [m] (a beam's deflection under its own weight).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import tcp_position


@dataclass(frozen=True)
class CyclicError:
    """Joint ``joint`` (0-based) turns ``amplitude_deg sin(cycles q + phase_rad)`` beyond its
    reading ``q``."""

    joint: int
    cycles: int
    amplitude_deg: float
    phase_rad: float = 0.0

    def deflection_rad(self, q_rad: np.ndarray) -> np.ndarray:
        """The link's turn beyond the reading [rad] (N,) at the readings ``q_rad`` (N, 6)."""
        return np.radians(self.amplitude_deg) * np.sin(self.cycles * q_rad[:, self.joint] + self.phase_rad)


@dataclass(frozen=True)
class Unmodelled:
    """The cyclic errors of some joints and a sag (mm per square metre of reach; 0: none)."""

    cyclic: tuple[CyclicError, ...] = ()
    sag_mm_per_m2: float = 0.0

    def link_angles(self, q_rad: np.ndarray) -> np.ndarray:
        """The angles [rad] (N, 6) the links take at the readings ``q_rad`` (N, 6)."""
        out = np.array(q_rad, float)
        for c in self.cyclic:
            out[:, c.joint] += c.deflection_rad(q_rad)
        return out

    def tcp_mm(self, dh: np.ndarray, q_rad: np.ndarray, tool_mm: np.ndarray) -> np.ndarray:
        """The true TCP (N, 3) [mm, base frame] of the table ``dh`` (6, 4) (rad, mm) at the
        readings ``q_rad`` (N, 6)."""
        p = tcp_position(dh, self.link_angles(q_rad), tool_mm)
        reach_m = np.hypot(p[:, 0], p[:, 1]) / 1000.0
        p[:, 2] -= self.sag_mm_per_m2 * reach_m**2
        return p


UR10_LIKE = Unmodelled(
    (CyclicError(1, 17, 0.014, 0.4), CyclicError(2, 17, 0.014, 2.1)),
    sag_mm_per_m2=0.15,
)
"""Joints 2 and 3 off by 50 arcsec 17 times a turn (what the real UR10 leaves: about 0.3 mm at the
TCP), and a sag of 0.15 mm at a metre's reach."""

KINDS = {"none": None, "ur10-like": UR10_LIKE}
"""The unmodelled errors a simulated cell may carry, by the name ``[sim] unmodelled`` gives."""


@dataclass(frozen=True)
class TrackerCell:
    """A UR10-sized arm with machining errors and ``unmodelled`` error, seen by a laser tracker:
    ``nominal`` and ``true`` tables (6, 4) (rad, mm), the probe ``probe_mm`` (3,) [mm, flange
    frame], the tracker's placement (``rotation`` (3, 3), ``translation_mm`` (3,)) and its noise
    ``sigma_mm`` per axis."""

    nominal: np.ndarray
    true: np.ndarray
    unmodelled: Unmodelled
    probe_mm: np.ndarray
    rotation: np.ndarray
    translation_mm: np.ndarray
    sigma_mm: float

    @classmethod
    def create(
        cls, nominal: np.ndarray, unmodelled: Unmodelled, seed: int, sigma_mm: float = 0.02
    ) -> TrackerCell:
        """Machining errors of 0.15 deg and 0.75 mm (1 sigma) on ``nominal`` drawn from ``seed``."""
        rng = np.random.default_rng(seed)
        angles = np.radians(rng.normal(0, 0.15, (6, 2)))
        true = nominal + np.column_stack([angles[:, 0], rng.normal(0, 0.75, (6, 2)), angles[:, 1]])
        rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        return cls(
            nominal,
            true,
            unmodelled,
            np.array([0.0, 0.0, 100.0]),
            rotation,
            np.array([2500.0, -1000.0, 200.0]),
            sigma_mm,
        )

    def true_point_mm(self, q_rad: np.ndarray) -> np.ndarray:
        """Where the probe truly is at the readings ``q_rad`` (N, 6), tracker frame [mm] (N, 3)."""
        return self.unmodelled.tcp_mm(self.true, q_rad, self.probe_mm) @ self.rotation.T + self.translation_mm

    def measure(self, q_rad: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The tracker's readings (N, 3) [mm] of the probe at ``q_rad`` (N, 6)."""
        p = self.true_point_mm(q_rad)
        return p + rng.normal(0.0, self.sigma_mm, p.shape)
