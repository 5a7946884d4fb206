"""Values published in Modbus registers: which encodings exist and where a device puts them.

A layout reads ``values`` consecutive numbers from ``address`` (first value first), each in
``encoding`` with ``word_order`` (``big``: high word first); a value is
``raw * encoding.unit_per_count * scale``. The drawstring's length and the joint registers of a
Modbus controller are both such layouts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from pymodbus.client import ModbusTcpClient

DataType = ModbusTcpClient.DATATYPE


@dataclass(frozen=True)
class Encoding:
    """How one value is held in registers: pymodbus data type and units (mm, deg) per raw count."""

    datatype: DataType
    unit_per_count: float


@dataclass(frozen=True)
class RegisterLayout:
    """Where and how a device publishes its values; subclasses name the ``ENCODINGS`` allowed and
    the number of ``VALUES``."""

    ENCODINGS: ClassVar[dict[str, Encoding]] = {}
    VALUES: ClassVar[int] = 1

    address: int = 0
    encoding: str = ""
    word_order: Literal["big", "little"] = "big"
    scale: float = 1.0
    device_id: int = 1
    table: Literal["holding", "input"] = "holding"

    def __post_init__(self):
        if self.encoding not in self.ENCODINGS:
            raise ValueError(f"encoding must be one of {sorted(self.ENCODINGS)}, got {self.encoding!r}")

    @property
    def count(self) -> int:
        """Registers for all values."""
        return self.VALUES * self.ENCODINGS[self.encoding].datatype.value[1]

    def decode(self, registers: list[int]) -> tuple[float, ...]:
        """The values (in units) from the raw registers."""
        enc = self.ENCODINGS[self.encoding]
        raw = ModbusTcpClient.convert_from_registers(registers, enc.datatype, self.word_order)
        raw = raw if isinstance(raw, list) else [raw]
        return tuple(float(r) * enc.unit_per_count * self.scale for r in raw)

    def encode(self, values) -> list[int]:
        """The registers a device publishes for ``values`` (inverse of :meth:`decode`; integer
        encodings round to the nearest count)."""
        enc = self.ENCODINGS[self.encoding]
        raw = [v / (enc.unit_per_count * self.scale) for v in values]
        if enc.datatype is not DataType.FLOAT32:
            raw = [round(r) for r in raw]
        return ModbusTcpClient.convert_to_registers(raw, enc.datatype, self.word_order)
