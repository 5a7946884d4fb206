"""Request/response ASCII instruments on a serial line (pyserial), one table of dialects.

A dialect is declared once: the request bytes, the line terminator, how a value is written
(``value_format``, used by the simulated devices) and read back (``value_re``), and how the device
reports an error (``error_re``). The driver sends the request, reads up to the terminator within
the timeout, and parses the reply; the simulated devices in ``sim_fixtures.serial_device`` answer
from the same table, and the byte-exact tests pin every dialect to literal bytes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import serial

try:  # a pty torn away mid-call raises termios.error (not an OSError) from tcflush
    from termios import error as TermiosError
except ImportError:  # pragma: no cover - not POSIX
    TermiosError = OSError

from drivers.base import (
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    Driver,
    Field,
    GarbledReply,
    Reading,
    excerpt,
)

MAX_REPLY_BYTES = 256  # a reply line longer than this is no instrument's: garbage


@dataclass(frozen=True)
class Dialect:
    """One ASCII protocol: ``request`` -> ``value_format.format(mm)`` + ``terminator``."""

    request: bytes
    terminator: bytes
    value_format: str  # str.format template of a reply, value in mm
    value_re: str  # regex with group "value" (mm) matching a whole reply line
    error_re: str  # regex with group "code" matching a whole error line
    error_format: str = "ERR{code}"  # how the device writes error ``code``

    def reply(self, value_mm: float) -> bytes:
        """The reply line for ``value_mm``, terminator included."""
        return self.value_format.format(value_mm).encode("ascii") + self.terminator

    def error(self, code: int) -> bytes:
        """The error line for ``code``, terminator included."""
        return self.error_format.format(code=code).encode("ascii") + self.terminator


DIALECTS: dict[str, Dialect] = {
    # Sylvac-style dial gauge: "?" CR -> "+0012.345" CR (mm, 3 decimals); "ERR3" = out of range.
    "sylvac": Dialect(
        request=b"?\r",
        terminator=b"\r",
        value_format="{:+09.3f}",
        value_re=r"(?P<value>[+-]\d{4}\.\d{3})",
        error_re=r"ERR(?P<code>\d+)",
    ),
    # Mitutoyo-style (Digimatic via a serial interface): "R" CR -> "01A+0000.123" CR,
    # "01A" = channel 01, unit mm; errors as "91<code>" (e.g. "913").
    "mitutoyo": Dialect(
        request=b"R\r",
        terminator=b"\r",
        value_format="01A{:+09.3f}",
        value_re=r"01A(?P<value>[+-]\d{4}\.\d{3})",
        error_re=r"91(?P<code>\d)",
        error_format="91{code}",
    ),
    # Drawstring sensor with a serial ASCII output: "M" CR LF -> "L+01234.567" CR LF (mm).
    "drawstring": Dialect(
        request=b"M\r\n",
        terminator=b"\r\n",
        value_format="L{:+010.3f}",
        value_re=r"L(?P<value>[+-]\d{5}\.\d{3})",
        error_re=r"E(?P<code>\d+)",
        error_format="E{code}",
    ),
}


def parse_reply(device: str, dialect: Dialect, line: bytes) -> float:
    """The value in mm of one reply line (terminator stripped).

    Raises :class:`DeviceReplyError` for the dialect's error line and :class:`GarbledReply` for
    anything else that is not a value.
    """
    text = line.decode("ascii", errors="replace")
    if match := re.fullmatch(dialect.value_re, text):
        return float(match["value"])
    if match := re.fullmatch(dialect.error_re, text):
        raise DeviceReplyError(device, f"device error {excerpt(repr(text), len(line))}", code=match["code"])
    raise GarbledReply(device, f"unparseable reply {excerpt(repr(line), len(line))}")


class AsciiSerialDriver(Driver):
    """One value (``field``, mm) read by request/response on a pyserial port.

    ``port`` is an unopened ``serial.Serial`` (e.g. ``serial.serial_for_url(path,
    do_not_open=True, timeout=...)``): the driver opens and closes it, and reopening it after an
    unplug finds the device again at the same path. Its ``timeout`` (s) bounds every reply.
    """

    def __init__(self, name: str, port: serial.Serial, dialect: Dialect, field: str, what: str):
        self.name = name
        self.port = port
        self.dialect = dialect
        self.fields = {field: Field("mm", (), what)}
        self._field = field

    def open(self) -> None:
        if self.port.is_open:
            return
        try:
            self.port.open()
        except (serial.SerialException, OSError) as exc:
            raise DeviceUnreachable(self.name, f"cannot open {self.port.port}: {exc}") from exc

    def close(self) -> None:
        self.port.close()

    def read(self) -> Reading:
        line = self._transact()
        value = parse_reply(self.name, self.dialect, line)
        return Reading.now(self.name, {self._field: value}, self.fields)

    def _transact(self) -> bytes:
        """Send the request and return the reply line without its terminator."""
        if not self.port.is_open:
            raise DeviceUnreachable(self.name, f"{self.port.port} is not open")
        term = self.dialect.terminator
        try:
            self.port.reset_input_buffer()
            self.port.write(self.dialect.request)
            raw = self.port.read_until(term, MAX_REPLY_BYTES)
        except (serial.SerialException, OSError, TermiosError) as exc:
            self.port.close()
            raise DeviceUnreachable(self.name, f"link lost on {self.port.port}: {exc}") from exc
        if not raw.endswith(term):
            if len(raw) >= MAX_REPLY_BYTES:
                raise GarbledReply(
                    self.name, f"no terminator in {excerpt(repr(raw), len(raw))}: the device floods bytes"
                )
            got = f"incomplete reply {excerpt(repr(raw), len(raw))}" if raw else "no reply"
            raise DeviceTimeout(self.name, f"{got} within {self.port.timeout} s")
        return raw[: -len(term)]
