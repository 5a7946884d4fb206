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

    def __init__(self):
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0


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
