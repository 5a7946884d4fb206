"""Simulated Modbus drawstring sensor: a pymodbus server (TCP, or RTU over a linked pty pair).

The sensor is one pymodbus ``SimDevice`` whose registers hold the length in the configured
:class:`drivers.drawstring.RegisterMap` layout. Each read request runs :meth:`_on_read` (the
SimDevice ``action``), which takes a fresh measurement (true length + noise, quantised to the
encoding's resolution, e.g. 1 um for ``int32_um``) and writes it into the registers the reply is
built from. Faults (``sim_fixtures.serial_device.FaultPlan``) act on the next requests:
``error`` answers Modbus exception 4 (device failure); ``nan`` / ``inf`` publish a float that is
no number (float32 layouts only); ``crc`` flips the last CRC byte of the RTU reply; ``garbled``
sends noise instead of the reply; ``silence`` sends nothing; ``unplug`` resets the TCP
connections (RST) or pulls the RTU cable at the station's end; ``stray`` answers as another
transaction (TCP) or another device id (RTU), a well-formed reply that is not the station's.

The server runs on its own asyncio loop in a daemon thread: :class:`ModbusDevice` starts it,
reports the bound address, and stops it within a bounded time.
"""

from __future__ import annotations

import asyncio
import socket
import struct
import threading
from collections.abc import Callable
from pathlib import Path

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerRTU
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.drawstring import RegisterMap
from sim_fixtures.serial_device import GARBAGE, FaultPlan, LinkedPtyPair

START_TIMEOUT_S = 5.0


class ModbusDevice:
    """A drawstring sensor serving ``measure()`` (mm) at ``registers``.

    Transport: ``tcp=(host, port)`` (port 0 picks a free one; see :attr:`address`) or
    ``rtu_link=Path`` (the station's end of a linked pty pair; the server opens the other end).
    """

    def __init__(
        self,
        registers: RegisterMap,
        measure: Callable[[], float],
        *,
        tcp: tuple[str, int] | None = None,
        rtu_link: Path | None = None,
        baudrate: int = 115200,
        faults: FaultPlan | None = None,
    ):
        if (tcp is None) == (rtu_link is None):
            raise ValueError("ModbusDevice needs exactly one of tcp=(host, port) or rtu_link=")
        self.registers = registers
        self.measure = measure
        self.faults = faults or FaultPlan()
        self.requests = 0
        self._tcp = tcp
        self._baudrate = baudrate
        self.cable = (
            LinkedPtyPair(rtu_link.with_name(f".{rtu_link.name}-device"), rtu_link) if rtu_link else None
        )
        self._fault: str | None = None
        self._server: ModbusTcpServer | ModbusSerialServer | None = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True, name="sim-modbus")
        self.address: dict = {}

    def _simdevice(self) -> SimDevice:
        regs = self.registers
        block = SimData(regs.address, count=regs.count, values=0, datatype=DataType.REGISTERS)
        return SimDevice(id=regs.device_id, simdata=[block], action=self._on_read)

    async def _on_read(self, function_code, start_address, address, count, registers, values):
        """SimDevice action: a fresh measurement into the registers, or an injected fault."""
        self.requests += 1
        self._fault = self.faults.take()
        if self._fault == "error":
            return ExcCodes.DEVICE_FAILURE
        offset = self.registers.address - start_address
        value = self.measure()
        if self._fault in ("nan", "inf"):
            value = self._no_number(value, float(self._fault))
        words = self._encode(value)
        registers[offset : offset + len(words)] = words
        return None

    @staticmethod
    def _no_number(value, bad: float):
        """``value`` (a length, or a joint vector) with its first number replaced by ``bad``."""
        return bad if isinstance(value, float | int) else [bad, *list(value)[1:]]

    def _encode(self, value) -> list[int]:
        """Registers for one measurement (a length in mm)."""
        return self.registers.encode_mm(value)

    def _on_packet(self, sending: bool, data: bytes) -> bytes:
        """Server packet hook: corrupt, replace or drop the outgoing reply under a fault."""
        fault, self._fault = (self._fault, None) if sending else (None, self._fault)
        if fault == "crc":
            return data[:-1] + bytes([data[-1] ^ 0xFF])
        if fault == "garbled":
            return GARBAGE
        if fault == "stray":
            return self._stray(data)
        if fault == "silence":
            return b""
        if fault == "unplug":
            self._unplug()
            return b""
        return data

    def _stray(self, reply: bytes) -> bytes:
        """``reply`` as another transaction's (TCP: transaction id + 1) or another device's (RTU:
        device id + 1, its CRC made right)."""
        if not self.cable:
            tid = (int.from_bytes(reply[:2], "big") + 1) % 0x10000
            return tid.to_bytes(2, "big") + reply[2:]
        frame = bytes([(reply[0] + 1) % 248]) + reply[1:-2]
        return frame + FramerRTU.compute_CRC(frame).to_bytes(2, "big")

    def unplug(self) -> None:
        """Pull the cable until :meth:`replug`: RTU, the station's end of the link disappears; TCP,
        the open connections are reset and new ones refused (the server stops listening)."""
        if self.cable:
            self.cable.unplug()
            return
        asyncio.run_coroutine_threadsafe(self._stop_serving(), self._loop).result(START_TIMEOUT_S)

    def replug(self) -> None:
        """Plug the cable back in: the same link (RTU) or the same address (TCP)."""
        if self.cable:
            self.cable.replug()
        elif self._server is None:
            asyncio.run_coroutine_threadsafe(self._serve(), self._loop).result(START_TIMEOUT_S)

    async def _stop_serving(self) -> None:
        if self._server is not None:
            self._unplug()
            server, self._server = self._server, None
            await server.shutdown()

    def _unplug(self) -> None:
        """The ``unplug`` fault: the RTU cable pulled, or the TCP connections reset."""
        if self.cable:
            self.cable.unplug()
            return
        for conn in list(self._server.active_connections.values()):
            sock = conn.transport.get_extra_info("socket")
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            conn.transport.abort()  # linger 0: the client sees a connection reset

    async def _serve(self) -> None:
        common = {"trace_packet": self._on_packet}
        if self.cable:
            self._server = ModbusSerialServer(
                self._simdevice(), port=self.cable.a.path, baudrate=self._baudrate, **common
            )
            self.address = {
                "protocol": "modbus-rtu",
                "port": str(self.cable.b.link),
                "baudrate": self._baudrate,
            }
        else:
            self._server = ModbusTcpServer(self._simdevice(), address=self._tcp, **common)
        await self._server.serve_forever(background=True)
        if not self.cable:
            host, port = self._server.transport.sockets[0].getsockname()[:2]
            self._tcp = (host, port)  # a replug serves the same address, also when port 0 chose it
            self.address = {"protocol": "modbus-tcp", "host": host, "port": port}
        self.address["device_id"] = self.registers.device_id

    def start(self) -> None:
        """Serve in the background; raises OSError/RuntimeError if the address is unusable."""
        if self.cable:
            self.cable.start()
        self._thread.start()
        future = asyncio.run_coroutine_threadsafe(self._serve(), self._loop)
        try:
            future.result(timeout=START_TIMEOUT_S)
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        if self._server is not None and self._loop.is_running():
            future = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            future.result(timeout=START_TIMEOUT_S)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=START_TIMEOUT_S)
        if not self._thread.is_alive():
            self._loop.close()
        if self.cable:
            self.cable.stop()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc_info):
        self.stop()
