"""Dial indicator on a serial line: Sylvac-style (default) or Mitutoyo-style ASCII dialect.

The dialects are rows of :data:`drivers.ascii.DIALECTS`; which one a station uses is
configuration (``[dial] dialect`` in ``configs/station.toml``).
"""

from __future__ import annotations

import serial

from drivers.ascii import DIALECTS, AsciiSerialDriver

DIAL_DIALECTS = ("sylvac", "mitutoyo")
DIAL_ERRORS = {
    "3": "out of range: the plunger is beyond its travel, so the tool is off the gauge edge (not "
    "touching it) or pressed in past the end; bring the tool onto the edge and read again",
}
"""What the indicator's error codes mean (``ERR3`` Sylvac-style, ``913`` Mitutoyo-style: code 3)."""


class DialIndicator(AsciiSerialDriver):
    """Reads ``dial_mm``: the indicator's displacement, mm, positive as the plunger goes in;
    ``error_meanings``: what its error codes mean (:data:`DIAL_ERRORS`)."""

    error_meanings = DIAL_ERRORS

    def __init__(self, port: serial.Serial, dialect: str = "sylvac", name: str = "dial"):
        if dialect not in DIAL_DIALECTS:
            raise ValueError(f"dial dialect must be one of {DIAL_DIALECTS}, got {dialect!r}")
        super().__init__(name, port, DIALECTS[dialect], "dial_mm", "dial indicator reading")
