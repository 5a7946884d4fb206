"""Simulated serial instruments on pseudo-terminals, with fault injection.

Each device owns the master end of a pty (``pty.openpty``); the driver opens the slave end, a real
``/dev/pts/N``, through a stable symlink (``/tmp/station-sim/<name>``) exactly as it would open
``/dev/ttyUSB0`` at a station. The slave is kept open by the device too, so the line stays up while
no driver is attached (a Linux pty master reads EIO once its last slave closes).

Faults (:class:`FaultPlan`) apply to the next requests: ``garbled`` (bytes outside the dialect),
``error`` (the dialect's error code 3, "out of range"), ``silence`` (no reply: the driver times
out) and ``unplug`` (the pty disappears mid-read; :meth:`PtyPort.replug` brings the device back
at the same link on a new ``/dev/pts/N``). ``crc`` (Modbus RTU), ``nan`` and ``inf`` (a float
register holding no number) and ``stray`` (another transaction's reply) are applied by the Modbus
device. :meth:`FaultPlan.every` repeats a fault on every n-th request, for as long as the device
runs.
"""

from __future__ import annotations

import collections
import os
import pty
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

from drivers.ascii import Dialect

FAULTS = ("garbled", "error", "silence", "unplug", "crc", "nan", "inf", "stray")
GARBAGE = b"+0\xff12.3#5"  # what a flipped bit or a loose ground makes of a reply
POLL_S = 0.05  # how often a device thread looks at its stop flag, s


class FaultPlan:
    """Faults queued for the next requests, oldest first (thread-safe); ``applied`` lists the
    faults taken so far as ``(time.monotonic(), kind)``."""

    def __init__(self):
        self._queue: collections.deque[str] = collections.deque()
        self._lock = threading.Lock()
        self.applied: list[tuple[float, str]] = []
        self._every: dict[str, int] = {}
        self._requests = 0
        self._drop: tuple[float, object] | None = None  # (fraction, generator) of requests left silent

    def inject(self, kind: str, count: int = 1) -> None:
        """Apply fault ``kind`` (one of :data:`FAULTS`) to the next ``count`` requests."""
        self._known(kind)
        with self._lock:
            self._queue.extend([kind] * count)

    def every(self, kind: str, n: int) -> None:
        """Apply fault ``kind`` to every ``n``-th request from now on (queued faults go first)."""
        self._known(kind)
        if n < 1:
            raise ValueError(f"every: n must be >= 1, got {n}")
        with self._lock:
            self._every[kind] = n

    def drop(self, fraction: float, rng) -> None:
        """Leave a random ``fraction`` of the requests unanswered ("silence"), drawn from ``rng``
        (a seeded ``numpy.random.Generator``), after any queued or periodic fault."""
        with self._lock:
            self._drop = (fraction, rng)

    @staticmethod
    def _known(kind: str) -> None:
        if kind not in FAULTS:
            raise ValueError(f"fault must be one of {FAULTS}, got {kind!r}")

    @property
    def pending(self) -> int:
        """Faults queued and not yet applied."""
        with self._lock:
            return len(self._queue)

    def take(self) -> str | None:
        """The fault for the request being answered, or None."""
        with self._lock:
            self._requests += 1
            if self._queue:
                kind = self._queue.popleft()
            else:
                kind = next((k for k, n in self._every.items() if self._requests % n == 0), None)
            if kind is None and self._drop is not None and self._drop[1].random() < self._drop[0]:
                kind = "silence"
            if kind is not None:
                self.applied.append((time.monotonic(), kind))
            return kind


def link_to(link: Path, target: str) -> None:
    """Point symlink ``link`` at ``target`` atomically (creating its folder)."""
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    tmp.symlink_to(target)
    tmp.replace(link)


class PtyPort:
    """A pty whose slave ``path`` (``/dev/pts/N``) is reachable at symlink ``link``.

    ``master`` is the device's end (raw bytes both ways). :meth:`unplug` closes it and removes the
    link; :meth:`replug` opens a fresh pty at the same link.
    """

    def __init__(self, link: Path):
        self.link = Path(link)
        self.master = -1
        self._slave = -1
        self.path = ""
        self.replug()

    def replug(self) -> None:
        self.master, self._slave = pty.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: bytes pass unchanged
        self.path = os.ttyname(self._slave)
        link_to(self.link, self.path)

    def unplug(self) -> None:
        """Remove the link, then close the pty: the driver sees the line drop only once the
        port reads as unplugged, so a replug that follows it always starts afresh."""
        if self.master < 0:
            return
        fds, self.master, self._slave = (self.master, self._slave), -1, -1
        if self.link.is_symlink() and os.readlink(self.link) == self.path:
            self.link.unlink()
        for fd in fds:
            os.close(fd)

    @property
    def plugged(self) -> bool:
        return self.master >= 0


class _Loop:
    """A daemon thread running ``step()`` every poll until stopped (bounded join)."""

    def __init__(self, name: str, step: Callable[[], None]):
        self._stop = threading.Event()
        self._step = step
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def idle(self) -> None:
        """Wait one poll period (or less, if stopped meanwhile)."""
        self._stop.wait(POLL_S)

    def _run(self) -> None:
        while not self._stop.is_set():
            self._step()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5 * POLL_S + 1.0)


class SerialAsciiDevice:
    """An ASCII request/response instrument of ``dialect`` on a pty at ``link``.

    Every complete request is answered with ``measure()`` (mm, noise included) in the dialect's
    format, or with error 3 when the value is outside ``range_mm`` (the instrument's travel).
    Use as a context manager, or ``start()`` / ``stop()``.
    """

    def __init__(
        self,
        link: Path,
        dialect: Dialect,
        measure: Callable[[], float],
        range_mm: tuple[float, float] = (-float("inf"), float("inf")),
        faults: FaultPlan | None = None,
    ):
        self.dialect = dialect
        self.measure = measure
        self.range_mm = range_mm
        self.faults = faults or FaultPlan()
        self.port = PtyPort(link)
        self.requests = 0  # requests answered or faulted, for tests and the benchmark
        self._buffer = b""
        self._loop = _Loop(f"sim-serial-{self.port.link.name}", self._poll)

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc_info):
        self.stop()

    def start(self) -> None:
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop()
        self.port.unplug()

    def unplug(self) -> None:
        """Pull the device's cable: the link disappears until :meth:`replug`."""
        self.port.unplug()

    def replug(self) -> None:
        """Bring the device back after an unplug, at the same link."""
        if not self.port.plugged:
            self._buffer = b""
            self.port.replug()

    def _poll(self) -> None:
        master = self.port.master
        if master < 0:
            self._loop.idle()
            return
        ready, _, _ = select.select([master], [], [], POLL_S)
        if not ready:
            return
        try:
            self._buffer += os.read(master, 4096)
        except OSError:  # unplugged meanwhile
            return
        request = self.dialect.request
        while request in self._buffer:
            _, _, self._buffer = self._buffer.partition(request)
            self._answer(master)

    def _answer(self, master: int) -> None:
        self.requests += 1
        fault = self.faults.take()
        if fault == "unplug":
            self.port.unplug()
            return
        reply = self._reply(fault)
        if reply:
            os.write(master, reply)

    def _reply(self, fault: str | None) -> bytes:
        """The bytes to send for one request under ``fault`` (empty: stay silent)."""
        if fault == "silence":
            return b""
        if fault == "garbled":
            return GARBAGE + self.dialect.terminator
        value = self.measure()
        low, high = self.range_mm
        if fault == "error" or not low <= value <= high:
            return self.dialect.error(3)
        return self.dialect.reply(value)


class LinkedPtyPair:
    """Two ptys joined like a null-modem cable: bytes written to ``a.path`` come out of
    ``b.path`` and back. ``a`` is the device's end, ``b`` (at ``link``) the station's; unplugging
    ``b`` is pulling the cable at the station."""

    def __init__(self, link_device: Path, link: Path):
        self.a = PtyPort(link_device)
        self.b = PtyPort(link)
        self._unplug = threading.Event()
        self._ends = threading.Lock()  # held while the ends are selected on, read, written or changed
        self._loop = _Loop(f"sim-cable-{self.b.link.name}", self._pump)

    def unplug(self) -> None:
        """Pull the cable at the station's end (done by the pump thread, between transfers)."""
        self._unplug.set()

    def replug(self) -> None:
        """Plug the station's end back in, at the same link on a new ``/dev/pts/N``; an unplugging
        the pump thread has not done yet is done first (on a busy machine the replug can come
        before it: the cable stayed pulled for good and a fault soak's session never ended)."""
        with self._ends:
            self._pull_if_asked()
            if not self.b.plugged:
                self.b.replug()

    def _pull_if_asked(self) -> None:
        """Do an asked-for unplugging (the ends' lock held)."""
        if self._unplug.is_set():
            self._unplug.clear()
            self.b.unplug()

    def start(self) -> None:
        self._loop.start()

    def stop(self) -> None:
        self._loop.stop()
        self.a.unplug()
        self.b.unplug()

    def _pump(self) -> None:
        with self._ends:
            self._pull_if_asked()
            ends = [p.master for p in (self.a, self.b) if p.plugged]
            if len(ends) == 2:
                try:
                    ready, _, _ = select.select(ends, [], [], POLL_S)
                    for fd in ready:
                        data = os.read(fd, 4096)
                        os.write(self.b.master if fd == self.a.master else self.a.master, data)
                    return
                except OSError:  # an end closed (the station's port shut): the bytes in flight are lost
                    pass
        self._loop.idle()  # outside the lock: a replug waits at most one transfer
