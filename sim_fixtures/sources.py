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


LIFTED_MM = 13.0
"""What a dial lifted off the edge reads: its plunger at the end of its travel (outside the range
of ``station_sim.DIAL_RANGE_MM``: the indicator answers with its error code)."""


@dataclass(frozen=True)
class CellSource:
    """The true state from a robot program (``SimRobot.state(t_s)``: joints, mode, target) and
    the cell (length, and dial against the line of the target the robot is at or moving to). A
    sweeping tool faster along the edge than ``liftoff_mm_s`` (simulated mm/s) lifts the dial off
    it, as it does inside the windows ``lifted`` ((start, end) simulated s into the program's
    cycle, ``cycle_s``, of every cycle: a bump on the edge mid-pass)."""

    robot: object  # sim_fixtures.robot_program.SimRobot or sim_fixtures.sweep_program.SweepRobot
    cell: Cell
    liftoff_mm_s: float = float("inf")
    lifted: tuple[tuple[float, float], ...] = ()

    def state(self, t_s: float) -> TrueState:
        robot = self.robot.state(t_s)
        q = robot.q_deg[None, :]
        line = self.cell.plan_lines[robot.target_index : robot.target_index + 1]
        sim_s = t_s * getattr(self.robot, "time_scale", 1.0)
        if self.lifted:
            sim_s %= self.robot.cycle_s
        off = robot.speed_mm_s > self.liftoff_mm_s or any(a <= sim_s < b for a, b in self.lifted)
        return TrueState(
            q_deg=tuple(robot.q_deg.tolist()),
            qd_deg_s=tuple(robot.qd_deg_s.tolist()),
            robot_mode=robot.robot_mode,
            length_mm=float(self.cell.true_length_mm(q)[0]),
            dial_mm=LIFTED_MM if off else float(self.cell.true_dial_mm(q, line)[0]),
        )
