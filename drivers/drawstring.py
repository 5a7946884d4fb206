"""Drawstring displacement sensor: Modbus RTU / Modbus TCP (pymodbus), or serial ASCII.

Modbus register layout is configuration (:class:`RegisterMap`); the encodings a sensor may use are
declared once in :data:`ENCODINGS`. Defaults: holding register 0, device id 1, ``int32_um``
(signed 32-bit micrometres, two registers), big-endian word order (high word first), scale 1.
The reading is ``length_mm = raw * encoding.unit_per_count * scale``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerRTU

from drivers.ascii import DIALECTS, AsciiSerialDriver
from drivers.base import (
    CrcError,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    Driver,
    Field,
    GarbledReply,
    Reading,
)
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


FUNCTION_CODES = {"holding": 3, "input": 4}  # Modbus read holding / read input registers

FIELDS = {"length_mm": Field("mm", (), "drawstring length reading")}


class ModbusDrawstring(Driver):
    """Drawstring sensor read over Modbus; ``client`` is an unconnected pymodbus sync client
    (``ModbusTcpClient`` or ``ModbusSerialClient`` with the RTU framer), best made with
    ``retries=0`` so that :func:`drivers.base.call_with_reconnect` owns the retry policy."""

    fields = FIELDS

    def __init__(
        self,
        client: ModbusTcpClient | ModbusSerialClient,
        registers: RegisterMap = RegisterMap(),
        name: str = "drawstring",
    ):
        self.name = name
        self.client = client
        self.registers = registers
        self._rx = b""  # raw bytes of the last reply, to tell a CRC error from silence
        client.transaction.trace_packet = self._trace  # pymodbus's packet hook, both ways

    def _trace(self, sending: bool, data: bytes) -> bytes:
        """Keep the bytes received since the last request (pymodbus passes the whole buffer)."""
        self._rx = b"" if sending else data
        return data

    def open(self) -> None:
        if not self.client.connect():
            raise DeviceUnreachable(self.name, f"cannot connect to {self._where()}")

    def close(self) -> None:
        self.client.close()

    def _where(self) -> str:
        params = self.client.comm_params
        port = f":{params.port}" if isinstance(self.client, ModbusTcpClient) else ""
        return f"{params.host}{port} device {self.registers.device_id}"

    def read(self) -> Reading:
        regs = self.registers
        return Reading.now(
            self.name, {"length_mm": regs.decode_mm(self._registers("length register"))}, FIELDS
        )

    def _registers(self, what: str) -> list[int]:
        """The mapped registers, raw; every pymodbus failure becomes a driver error naming ``what``."""
        regs = self.registers
        reader = (
            self.client.read_holding_registers
            if regs.table == "holding"
            else self.client.read_input_registers
        )
        try:
            reply = reader(regs.address, count=regs.count, device_id=regs.device_id)
        except (ModbusException, OSError) as exc:
            raise self._classify(exc) from exc
        if reply.isError():
            raise DeviceReplyError(
                self.name,
                f"Modbus exception code {reply.exception_code} reading {what} "
                f"{regs.address}..{regs.address + regs.count - 1}",
                code=str(reply.exception_code),
            )
        if len(reply.registers) != regs.count:
            raise GarbledReply(self.name, f"{len(reply.registers)} registers, {regs.count} asked")
        return reply.registers

    def _classify(self, exc: Exception) -> Exception:
        """The driver error behind a pymodbus failure: lost link, CRC, garbage or silence."""
        if isinstance(exc, OSError) or not self.client.connected:
            self.client.close()
            return DeviceUnreachable(self.name, f"link lost to {self._where()}: {exc}")
        rx = self._rx
        if isinstance(self.client, ModbusSerialClient) and self._is_bad_crc_reply(rx):
            return CrcError(self.name, f"bad CRC in reply {rx.hex(' ')}")
        if rx:
            return GarbledReply(self.name, f"unparseable reply {rx.hex(' ')}")
        timeout = self.client.comm_params.timeout_connect
        return DeviceTimeout(self.name, f"no reply from {self._where()} within {timeout} s")

    def _is_bad_crc_reply(self, rx: bytes) -> bool:
        """Whether ``rx`` is a reply frame from our device (id, function) whose CRC is wrong."""
        regs = self.registers
        return (
            len(rx) >= 5
            and rx[0] == regs.device_id
            and rx[1] & 0x7F == FUNCTION_CODES[regs.table]
            and not FramerRTU.check_CRC(rx[:-2], int.from_bytes(rx[-2:], "big"))
        )


class AsciiDrawstring(AsciiSerialDriver):
    """Drawstring sensor with a serial ASCII output (dialect ``drawstring``): ``length_mm``."""

    def __init__(self, port: serial.Serial, name: str = "drawstring"):
        what = FIELDS["length_mm"].description
        super().__init__(name, port, DIALECTS["drawstring"], "length_mm", what)
