"""Drawstring displacement sensor: Modbus RTU / Modbus TCP (pymodbus), or serial ASCII.

Over Modbus it is a device on :class:`drivers.modbus.ModbusRegisterDriver`; its register layout is
configuration (:class:`RegisterMap`) and the encodings a sensor may use are declared once in
:data:`ENCODINGS`. Defaults: holding register 0, device id 1, ``int32_um``
(signed 32-bit micrometres, two registers), big-endian word order (high word first), scale 1.
The reading is ``length_mm = raw * encoding.unit_per_count * scale``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.ascii import DIALECTS, AsciiSerialDriver
from drivers.base import Field
from drivers.modbus import ModbusRegisterDriver
from drivers.registers import DataType, Encoding, RegisterLayout

ENCODINGS: dict[str, Encoding] = {
    "int32_um": Encoding(DataType.INT32, 0.001),  # signed micrometres, 1 um resolution
    "float32_mm": Encoding(DataType.FLOAT32, 1.0),  # IEEE-754 single, millimetres
}


@dataclass(frozen=True)
class RegisterMap(RegisterLayout):
    """Where and how the sensor publishes its length (see the module docstring for defaults)."""

    ENCODINGS: ClassVar[dict[str, Encoding]] = ENCODINGS
    encoding: str = "int32_um"

    def decode_mm(self, registers: list[int]) -> float:
        """Length in mm from the raw registers."""
        return self.decode(registers)[0]

    def encode_mm(self, length_mm: float) -> list[int]:
        """The registers a sensor publishes for ``length_mm`` (the inverse of ``decode_mm``)."""
        return self.encode([length_mm])


FIELDS = {"length_mm": Field("mm", (), "drawstring length reading")}


class ModbusDrawstring(ModbusRegisterDriver):
    """Drawstring sensor read over Modbus (see :class:`drivers.modbus.ModbusRegisterDriver` for
    ``client``): ``length_mm`` from the length register."""

    fields = FIELDS
    field = "length_mm"
    what = "length register"

    def __init__(
        self,
        client: ModbusTcpClient | ModbusSerialClient,
        registers: RegisterMap = RegisterMap(),
        name: str = "drawstring",
    ):
        super().__init__(client, registers, name)


class AsciiDrawstring(AsciiSerialDriver):
    """Drawstring sensor with a serial ASCII output (dialect ``drawstring``): ``length_mm``."""

    def __init__(self, port: serial.Serial, name: str = "drawstring"):
        what = FIELDS["length_mm"].description
        super().__init__(name, port, DIALECTS["drawstring"], "length_mm", what)
