"""Each device read continuously in its own thread, every reading time-stamped where it is taken
(a sweep session, ``station.acquire.sweep``).

- The robot: its driver polled twice per package period (a subscription's, as ROS's, drained as
  often: every message it pushed, stamped at its arrival); each new package is kept with the
  controller's timestamp (RTDE's ``controller_time_s``, an OPC UA server's source timestamp) and
  its arrival on the station's clock (``time.monotonic``), so the two clocks can be tied
  (``calib.alignment.clock_offset``). A source without a controller timestamp (OPC UA and Modbus
  polled), or whose clock stands still while its joints move (a ROS stamp of 0), is stamped at the
  middle of its read, as a sensor is (a pushed message: at its arrival), and kept when its joints
  change.
- A sensor (drawstring, dial): asked again as soon as it answers, but not sooner than
  ``min_interval_s`` after its last request (twice the rows a sweep keeps: more would only load
  the station); a reading is stamped at the
  middle of its request and reply (the device measures between the two), with that round trip.
  An error reply (a dial off the edge, out of range) is kept as NaN: the dial said "not on the
  edge". An unanswered request (a timeout, a garbled or failed reply) is counted, never filled in;
  ``RECONNECT_AFTER`` of them in a row reopen the device.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np

from drivers.base import DeviceReplyError, Driver, DriverError

RECONNECT_AFTER = 20  # unanswered requests in a row before a sensor is reopened
ROBOT_POLLS_PER_PACKAGE = 2
STILL_CLOCK = 5  # packages in a row with new joints and the same stamp: the source's clock stands still


@dataclass
class SensorStream:
    """A sensor's readings so far: times [s, station clock], values (NaN: an error reply), round
    trips [s]; ``requests`` made and ``unanswered`` of them, the last failure's text."""

    name: str
    field: str
    t: list[float] = field(default_factory=list)
    value: list[float] = field(default_factory=list)
    round_trip: list[float] = field(default_factory=list)
    requests: int = 0
    unanswered: int = 0
    last_failure: str = ""

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = len(self.t)  # the reader appends t last: a snapshot of n whole readings
        return np.array(self.t[:n]), np.array(self.value[:n]), np.array(self.round_trip[:n])


@dataclass
class RobotStream:
    """The robot's packages so far: controller timestamps and arrivals [s], joints [deg], joint
    speeds [deg/s], robot modes; ``stamped``: whether the source has a controller clock."""

    stamp: list[float] = field(default_factory=list)
    arrival: list[float] = field(default_factory=list)
    q_deg: list[tuple] = field(default_factory=list)
    qd_deg_s: list[tuple] = field(default_factory=list)
    mode: list[int] = field(default_factory=list)
    stamped: bool = True
    failures: int = 0
    last_failure: str = ""

    def clear(self) -> None:
        """Forget the packages so far (their stamps were the controller's: no longer the base)."""
        for name in ("arrival", "stamp", "q_deg", "qd_deg_s", "mode"):
            getattr(self, name).clear()

    def arrays(self) -> dict[str, np.ndarray]:
        n = len(self.arrival)  # appended last
        return {
            "stamp": np.array(self.stamp[:n]),
            "arrival": np.array(self.arrival[:n]),
            "q_deg": np.array(self.q_deg[:n], float).reshape(-1, 6),
            "qd_deg_s": np.array(self.qd_deg_s[:n], float).reshape(-1, 6),
            "mode": np.array(self.mode[:n], int),
        }


class Streams:
    """Reader threads for the robot and each sensor of ``drivers`` (``robot``, ``drawstring``,
    optional ``dial``), from :meth:`start` to :meth:`stop`; ``robot_hz``: the robot's package rate,
    ``min_interval_s`` [s]: the least time between two requests to a sensor."""

    def __init__(self, drivers: dict[str, Driver], robot_hz: float, min_interval_s: float = 0.0):
        self.drivers = drivers
        self.robot = RobotStream()
        self.sensors = {
            name: SensorStream(name, f"{name}_mm" if name == "dial" else "length_mm")
            for name in ("drawstring", "dial")
            if name in drivers
        }
        self._poll_s = 1.0 / (ROBOT_POLLS_PER_PACKAGE * robot_hz)
        self._min_interval_s = min_interval_s
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        targets = [(self._read_robot, ())] + [(self._read_sensor, (s,)) for s in self.sensors.values()]
        for target, args in targets:
            thread = threading.Thread(target=target, args=args, daemon=True, name="station-stream")
            thread.start()
            self._threads.append(thread)

    def stop(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=2.0)

    def _read_robot(self) -> None:
        driver, keep = self.drivers["robot"], _Keeper(self.robot)
        while not self._stop.is_set():
            before = time.monotonic()
            try:
                pushed = driver.received()
                if pushed is None:  # polled: a reading taken somewhere inside the read
                    reading = driver.read()
                    keep(reading, (before + reading.t_monotonic) / 2)
                for reading in pushed or ():  # a subscription's: each sent as it arrived
                    keep(reading, reading.t_monotonic)
            except DriverError as exc:
                self.robot.failures += 1
                self.robot.last_failure = str(exc)
                self._stop.wait(self._poll_s * 10)
                continue
            self._stop.wait(self._poll_s)

    def _read_sensor(self, out: SensorStream) -> None:
        driver, failing = self.drivers[out.name], 0
        before = -float("inf")
        while not self._stop.is_set():
            wait = before + self._min_interval_s - time.monotonic()
            if wait > 0:
                self._stop.wait(wait)
            before = time.monotonic()
            out.requests += 1
            try:
                value = float(driver.read().values[out.field])
            except DeviceReplyError:
                value = float("nan")  # it answered: not a measurement (a dial off the edge)
            except DriverError as exc:
                out.unanswered += 1
                out.last_failure = exc.cause
                failing += 1
                if failing >= RECONNECT_AFTER:
                    failing = 0
                    _reopen(driver)
                continue
            after = time.monotonic()
            failing = 0
            out.value.append(value)
            out.round_trip.append(after - before)
            out.t.append((before + after) / 2)


class _Keeper:
    """Appends each new package to a :class:`RobotStream`: one with new joints or a new stamp, on
    the controller's clock while the source has one that runs, else at ``taken`` [s, monotonic]."""

    def __init__(self, out: RobotStream):
        self.out, self.last, self.still = out, (None, None), 0

    def __call__(self, reading, taken: float) -> None:
        out, v = self.out, reading.values
        stamp, q = v.get("controller_time_s"), tuple(v["q_deg"])
        self.still = (
            self.still + 1 if stamp is not None and stamp == self.last[0] and q != self.last[1] else 0
        )
        if out.stamped and (stamp is None or self.still >= STILL_CLOCK):
            out.stamped = False  # no clock, or one standing still on moving joints
            out.clear()
        if (stamp, q) != self.last and (not out.stamped or self.still == 0):
            self.last = (stamp, q)
            out.stamp.append(float(stamp if out.stamped else taken))
            out.q_deg.append(q)
            out.qd_deg_s.append(tuple(v["qd_deg_s"]))
            out.mode.append(int(v["robot_mode"]))
            out.arrival.append(reading.t_monotonic)


def _reopen(driver: Driver) -> None:
    """Close and open a device that stopped answering (a failed open is tried again later)."""
    try:
        driver.close()
        driver.open()
    except DriverError:
        time.sleep(0.05)
