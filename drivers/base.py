"""The protocol every instrument driver follows, its errors, and the reconnect helper.

A driver receives its connection settings from outside, opens the transport in ``open()`` (or
``with driver:``), and answers ``read()`` with one :class:`Reading`: named values, their units and
when they were taken (monotonic clock for intervals, wall clock for the record). ``describe()``
says what ``read()`` returns without touching the device.

Every failure is a :class:`DriverError` naming the device and the cause. Transient ones (timeout,
CRC, garbled reply, lost link) are retried by :func:`call_with_reconnect`, which closes, waits with
exponential backoff, reopens and tries again, and raises :class:`DeviceUnreachable` when the
attempts are spent. A device that answers with an error code (:class:`DeviceReplyError`, e.g.
``ERR3`` out of range) is reachable: that is not retried.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

from errors import DeviceError

T = TypeVar("T")

Value = float | tuple[float, ...] | int


@dataclass(frozen=True)
class Field:
    """What one value of a reading is: its units, its shape (``()`` for a scalar) and meaning."""

    units: str
    shape: tuple[int, ...] = ()
    description: str = ""


@dataclass(frozen=True)
class Reading:
    """One reading of a device.

    ``values`` maps field names to numbers (tuples for vectors, e.g. six joints in degrees);
    ``units`` maps the same names to their units. ``t_monotonic`` (s, ``time.monotonic``) is
    for intervals and ``t_wall`` (s since the epoch, ``time.time``) for the record; both are
    taken when the reply arrived.
    """

    device: str
    values: Mapping[str, Value]
    units: Mapping[str, str]
    t_monotonic: float
    t_wall: float

    @classmethod
    def now(cls, device: str, values: Mapping[str, Value], fields: Mapping[str, Field]) -> Reading:
        """A reading stamped with the current clocks, units taken from ``fields``."""
        return cls(
            device=device,
            values=dict(values),
            units={name: fields[name].units for name in values},
            t_monotonic=time.monotonic(),
            t_wall=time.time(),
        )


MAX_JOINT_DEG = 3600.0
"""Ten turns: a joint reading beyond it is no robot's (``station.formats`` refuses it in a file too)."""

EXCERPT_CHARS = 80  # what a device's reply contributes to a message, at most


def excerpt(text: str, n_bytes: int | None = None) -> str:
    """``text`` (a device's reply as a message shows it: hex or repr) cut to ``EXCERPT_CHARS``
    characters, with the reply's size (``n_bytes``) said: a device flooding bytes does not flood
    the log."""
    if len(text) <= EXCERPT_CHARS:
        return text
    size = f"{n_bytes} bytes" if n_bytes is not None else f"{len(text)} characters"
    return f"{text[:EXCERPT_CHARS]}... ({size})"


class DriverError(DeviceError):
    """A device failed; ``device`` names it and ``cause`` says how."""

    def __init__(self, device: str, cause: str):
        super().__init__(f"{device}: {cause}")
        self.device = device
        self.cause = cause


class DeviceTimeout(DriverError):
    """No (complete) reply within the timeout."""


class CrcError(DriverError):
    """A frame arrived with a wrong checksum."""


class GarbledReply(DriverError):
    """A reply arrived but does not parse in the device's protocol."""


class DeviceReplyError(DriverError):
    """The device answered with an error code (e.g. ``ERR3``: reading out of range)."""

    def __init__(self, device: str, cause: str, code: str):
        super().__init__(device, cause)
        self.code = code


class IncompatibleDevice(DriverError):
    """The device answers, but not as the station needs (e.g. an RTDE recipe of other types): not
    retried, and no sign of a reachable device either."""


class DeviceUnreachable(DriverError):
    """The link is down (port missing, connection refused or reset) or stayed down after retries."""


RETRYABLE = (DeviceTimeout, CrcError, GarbledReply, DeviceUnreachable)


class Driver(abc.ABC):
    """Base of every driver: context-managed open/close, ``read()`` and ``describe()``.

    Subclasses set ``name`` (the device's name in messages and readings) and ``fields``.
    """

    name: str
    fields: Mapping[str, Field]
    no_channel: str | None = "a robot connection of this kind has none"
    """Why :meth:`target_channel` gives None (where it does)."""
    clock_may_stand_still: bool = False
    """Whether the source's clock (a robot's ``controller_time_s``) may stand still while its readings
    are fresh (a value stamped when it changes, or not at all): a session then times the robot's
    rest on their arrival. False: a clock standing still is a stalled stream repeating old data."""

    @abc.abstractmethod
    def open(self) -> None:
        """Open the transport; raise :class:`DeviceUnreachable` if it cannot be opened."""

    @abc.abstractmethod
    def close(self) -> None:
        """Close the transport; safe to call twice or on a driver never opened."""

    @abc.abstractmethod
    def read(self) -> Reading:
        """One reading of every field, or a :class:`DriverError`."""

    def received(self) -> list[Reading] | None:
        """Every reading the device pushed since the last call (a subscription), oldest first, each
        stamped at its arrival; None where the device is polled (:meth:`read` it instead)."""
        return None

    def describe(self) -> dict[str, Field]:
        """What :meth:`read` returns: field name -> units, shape, meaning."""
        return dict(self.fields)

    def target_channel(self) -> TargetChannel | None:
        """Where this (robot) device hands a running program corrected targets, once opened; None
        where it has no such channel."""
        return None

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


class TargetChannel(Protocol):
    """A robot controller's inputs that a running measurement program reads before it moves to a
    target (``station program``): ``write`` hands it target ``target``'s corrected contact joints
    ``q_deg`` (6,) [deg] (a :class:`DriverError` if the controller does not take them); ``where``
    says which inputs, for the operator."""

    where: str

    def write(self, target: int, q_deg: Sequence[float]) -> None: ...


@dataclass(frozen=True)
class Backoff:
    """Retry schedule: ``attempts`` tries in all, waiting ``initial_s * factor**k`` (at most
    ``max_s``) seconds before retry ``k + 1``."""

    attempts: int = 4
    initial_s: float = 0.05
    factor: float = 2.0
    max_s: float = 1.0

    def __post_init__(self):
        if self.attempts < 1:
            raise ValueError(f"Backoff.attempts must be >= 1, got {self.attempts}")

    def delays(self) -> Iterator[float]:
        """The waits between attempts, s (``attempts - 1`` of them)."""
        for k in range(self.attempts - 1):
            yield min(self.initial_s * self.factor**k, self.max_s)


def call_with_reconnect(
    driver: Driver,
    call: Callable[[], T],
    backoff: Backoff = Backoff(),
    sleep: Callable[[float], None] = time.sleep,
    on_retry: Callable[[DriverError], None] = lambda exc: None,
) -> T:
    """``call()``, retried on transient failures with a reconnect of ``driver`` in between.

    Between attempts the driver is closed, ``sleep`` waits the next backoff delay, and the driver is
    reopened (a failed reopen counts as a failed attempt); ``on_retry(error)`` hears of each failure
    that a retry follows. :class:`DeviceReplyError` and non-driver errors pass straight through.
    After the last attempt raises :class:`DeviceUnreachable` naming the device, the number of
    attempts and the last cause.
    """
    last: DriverError | None = None
    for delay in (None, *backoff.delays()):
        try:
            if delay is not None:
                on_retry(last)
                driver.close()
                sleep(delay)
                driver.open()
            return call()
        except RETRYABLE as exc:
            last = exc
    raise DeviceUnreachable(
        driver.name, f"unreachable after {backoff.attempts} attempts ({last.cause})"
    ) from last
