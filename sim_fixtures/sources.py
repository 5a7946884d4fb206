"""What the simulated devices measure: a clock, a source of true values, an instrument model.

The simulated devices ask a :class:`Source` for the true state of the world ``t_s`` real seconds
after the simulation started (:class:`SimClock`) and add their instrument's noise and resolution on
top (:class:`Instrument`). A source that moves (the simulated robot program) applies the shared
``time_scale`` itself, like ``SimRobot.state``. ``sim serve`` plugs the simulated robot and world
in as the source; tests use :class:`FixedSource`.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass(frozen=True)
class TrueState:
    """Noise-free state at one instant: joints (deg, deg/s), controller mode, readings (mm)."""

    q_deg: tuple[float, ...]
    qd_deg_s: tuple[float, ...]
    robot_mode: int
    length_mm: float
    dial_mm: float


class Source(Protocol):
    """Anything that gives the true state ``t_s`` real seconds after the simulation started."""

    def state(self, t_s: float) -> TrueState: ...


@dataclass(frozen=True)
class FixedSource:
    """A world that holds still: the same state at every time (tests, ``--hold``)."""

    fixed: TrueState

    def state(self, t_s: float) -> TrueState:
        return self.fixed


class SimClock:
    """Real seconds since the simulation started, shared by every simulated device."""

    def __init__(self, start_monotonic: float | None = None):
        self.start_monotonic = time.monotonic() if start_monotonic is None else start_monotonic

    def now(self) -> float:
        return time.monotonic() - self.start_monotonic


@dataclass
class Instrument:
    """A length instrument: Gaussian noise of ``sigma_mm`` (1 sigma), then quantised to
    ``resolution_mm`` (the last digit the device shows); ``rng`` is the seeded noise source."""

    sigma_mm: float
    resolution_mm: float
    rng: np.random.Generator
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def measure(self, true_mm: float) -> float:
        """One reading of ``true_mm``, mm (thread-safe: devices share the generator's stream)."""
        with self._lock:
            noisy = true_mm + self.rng.normal(0.0, self.sigma_mm)
        return round(noisy / self.resolution_mm) * self.resolution_mm


class Cell(Protocol):
    """The true cell the instruments measure (``sim_fixtures.world.World`` offers the two
    methods): noise-free drawstring and dial readings (mm) for configurations (N, 6) in degrees,
    and the plan the robot program walks: ``plan_deg`` (M, 6), line ids ``plan_lines`` (M,)."""

    plan_deg: np.ndarray
    plan_lines: np.ndarray

    def true_length_mm(self, q_deg) -> np.ndarray: ...

    def true_dial_mm(self, q_deg, line_ids) -> np.ndarray: ...


def dh_tcp_mm(table: np.ndarray, q_deg) -> np.ndarray:
    """TCP (N, 3), mm, of the standard D-H ``table`` (6, 4) with rows (alpha_deg, a_mm, d_mm,
    theta_deg) at ``q_deg`` (N, 6): ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``,
    tool at the flange origin."""
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    pose = np.broadcast_to(np.eye(4), (len(q), 4, 4))
    for (alpha_deg, a, d, theta_deg), qi in zip(table, q.T, strict=True):
        th, al = np.radians(theta_deg + qi), np.radians(alpha_deg)
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.full_like(th, np.cos(al)), np.full_like(th, np.sin(al))
        zero, one = np.zeros_like(th), np.ones_like(th)
        link = np.stack(
            [
                np.stack([ct, -st * ca, st * sa, a * ct], axis=-1),
                np.stack([st, ct * ca, -ct * sa, a * st], axis=-1),
                np.stack([zero, sa, ca, d * one], axis=-1),
                np.stack([zero, zero, zero, one], axis=-1),
            ],
            axis=1,
        )
        pose = pose @ link
    return pose[:, :3, 3]


@dataclass(frozen=True)
class StandInCell:
    """A small stand-in for ``sim_fixtures.world.World`` until it is merged: the nominal robot
    ``table`` taken as true, a drawstring anchored at ``anchor_mm`` with ``length_offset_mm``,
    and one horizontal gauge edge at the height of the first target, read by a dial along +z
    (``dial_mm`` = TCP height above the edge). The plan: the working pose swung about joint 1."""

    table: np.ndarray
    anchor_mm: np.ndarray = field(default_factory=lambda: np.array([-800.0, 600.0, -600.0]))
    length_offset_mm: float = 200.0
    plan_deg: np.ndarray = field(
        default_factory=lambda: np.array(
            [[q1, -50.0, -20.0, 0.0, -90.0, 0.0] for q1 in (-10.0, -5.0, 0.0, 5.0, 10.0)]
        )
    )

    @property
    def plan_lines(self) -> np.ndarray:
        return np.zeros(len(self.plan_deg), dtype=int)

    def true_length_mm(self, q_deg) -> np.ndarray:
        tcp = dh_tcp_mm(self.table, q_deg)
        return np.linalg.norm(tcp - self.anchor_mm, axis=1) - self.length_offset_mm

    def true_dial_mm(self, q_deg, line_ids) -> np.ndarray:
        edge_z = dh_tcp_mm(self.table, self.plan_deg[0])[0, 2]
        return dh_tcp_mm(self.table, q_deg)[:, 2] - edge_z


@dataclass(frozen=True)
class CellSource:
    """The true state from a robot program (``SimRobot.state(t_s)``: joints, mode, target) and
    the cell (length, and dial against the line of the target the robot is at or moving to)."""

    robot: object  # sim_fixtures.robot_program.SimRobot
    cell: Cell

    def state(self, t_s: float) -> TrueState:
        robot = self.robot.state(t_s)
        q = robot.q_deg[None, :]
        line = self.cell.plan_lines[robot.target_index : robot.target_index + 1]
        return TrueState(
            q_deg=tuple(robot.q_deg.tolist()),
            qd_deg_s=tuple(robot.qd_deg_s.tolist()),
            robot_mode=robot.robot_mode,
            length_mm=float(self.cell.true_length_mm(q)[0]),
            dial_mm=float(self.cell.true_dial_mm(q, line)[0]),
        )
