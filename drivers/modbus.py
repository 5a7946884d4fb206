"""One Modbus register driver (pymodbus, TCP or RTU) for every device that publishes its values in
registers; a device on it only says which field its values fill.

The driver owns the transport (an unconnected pymodbus sync client passed in, best made with
``retries=0`` so that :func:`drivers.base.call_with_reconnect` owns the retry policy), reads the
registers a :class:`~drivers.registers.RegisterLayout` names, and turns every pymodbus failure into
a driver error naming the device: lost link, bad CRC (RTU), garbage, silence, or the device's own
exception code.
"""

from __future__ import annotations

import logging
import math
from typing import ClassVar

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerRTU

from drivers.base import (
    CrcError,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    Driver,
    GarbledReply,
    Reading,
    excerpt,
)
from drivers.registers import RegisterLayout

FUNCTION_CODES = {"holding": 3, "input": 4}  # Modbus read holding / read input registers
MBAP_UNIT = 6  # Modbus TCP: the unit id's offset in a frame (after transaction, protocol, length)

# pymodbus logs every failure itself ("No response received ...", "Repeating....") on stderr; the
# driver raises each one, named, and the session logs it: its own lines would only add noise.
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


class ModbusRegisterDriver(Driver):
    """A device read over Modbus: ``read()`` fills the one field ``field`` of ``fields`` with the
    values of ``layout`` (a scalar field takes the first value, a vector field all of them).

    Subclasses set ``fields``, ``field`` and ``what`` (the registers as messages name them).
    """

    field: ClassVar[str]
    what: ClassVar[str]

    def __init__(self, client: ModbusTcpClient | ModbusSerialClient, layout: RegisterLayout, name: str):
        self.name = name
        self.client = client
        self.registers = layout
        self._rx = b""  # raw bytes of the last reply, to tell a CRC error from silence
        self._tx = b""  # the last request's frame, to tell a stray reply from garbage
        client.transaction.trace_packet = self._trace  # pymodbus's packet hook, both ways

    def _trace(self, sending: bool, data: bytes) -> bytes:
        """Keep the last request and the bytes received since (pymodbus passes the whole buffer)."""
        if sending:
            self._tx, self._rx = data, b""
        else:
            self._rx = data
        return data

    def open(self) -> None:
        if not self.client.connect():
            raise DeviceUnreachable(self.name, f"cannot connect to {self._where()}")

    def close(self) -> None:
        self.client.close()

    def read(self) -> Reading:
        values = self.registers.decode(self._read_registers())
        if not all(math.isfinite(v) for v in values):
            regs = self.registers
            raise GarbledReply(
                self.name,
                f"{self.what} {regs.address}..{regs.address + regs.count - 1} hold no number "
                f"({', '.join(f'{v:g}' for v in values)})",
            )
        value = values if self.fields[self.field].shape else values[0]
        return Reading.now(self.name, {self.field: value}, self.fields)

    def _where(self) -> str:
        params = self.client.comm_params
        port = f":{params.port}" if isinstance(self.client, ModbusTcpClient) else ""
        return f"{params.host}{port} device {self.registers.device_id}"

    def _read_registers(self) -> list[int]:
        """The layout's registers, raw; every pymodbus failure becomes a driver error."""
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
                f"Modbus exception code {reply.exception_code} reading {self.what} "
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
            return CrcError(self.name, f"bad CRC in reply {excerpt(rx.hex(' '), len(rx))}")
        if stray := self._stray(rx):
            return GarbledReply(self.name, f"{stray}: {excerpt(rx.hex(' '), len(rx))}")
        if rx:
            return GarbledReply(self.name, f"unparseable reply {excerpt(rx.hex(' '), len(rx))}")
        timeout = self.client.comm_params.timeout_connect
        return DeviceTimeout(self.name, f"no reply from {self._where()} within {timeout} s")

    def _stray(self, rx: bytes) -> str | None:
        """What a well-formed reply that is not ours was (pymodbus skips it, then times out): a
        reply to another transaction (TCP: a late reply, or another client) or from another
        device id (another device on the line or behind the gateway); None if it is neither."""
        unit_at = 0 if isinstance(self.client, ModbusSerialClient) else MBAP_UNIT
        if len(rx) < unit_at + 2 or rx[unit_at + 1] & 0x7F != FUNCTION_CODES[self.registers.table]:
            return None
        if unit_at and len(self._tx) >= 2 and rx[:2] != self._tx[:2]:
            got, ours = int.from_bytes(rx[:2], "big"), int.from_bytes(self._tx[:2], "big")
            return f"a reply to transaction {got}, not to ours ({ours}): a late reply or another client"
        if rx[unit_at] != self.registers.device_id:
            ours = self.registers.device_id
            return f"a reply from device id {rx[unit_at]}, not {ours}: another device answered"
        return None

    def _is_bad_crc_reply(self, rx: bytes) -> bool:
        """Whether ``rx`` is a reply frame from our device (id, function) whose CRC is wrong."""
        regs = self.registers
        return (
            len(rx) >= 5
            and rx[0] == regs.device_id
            and rx[1] & 0x7F == FUNCTION_CODES[regs.table]
            and not FramerRTU.check_CRC(rx[:-2], int.from_bytes(rx[-2:], "big"))
        )
