"""Round-trip latency of each instrument driver against its simulated device: p50 / p99, ms.

Every driver runs through its real client (pyserial on a pty, pymodbus TCP / RTU on a linked pty
pair) against the simulated device in this process, one request at a time, as the station polls.
A pty moves bytes at memory speed whatever its baud rate, so for serial links the script also
prints the time the request and reply frames alone take on a real line at the nominal rate
(10 bits per byte): add it to the measured figure for a station estimate.

    python benchmarks/drivers_latency.py [--reads N] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.ascii import DIALECTS  # noqa: E402
from drivers.dial import DialIndicator  # noqa: E402
from drivers.drawstring import AsciiDrawstring, ModbusDrawstring, RegisterMap  # noqa: E402
from sim_fixtures.modbus_device import ModbusDevice  # noqa: E402
from sim_fixtures.serial_device import SerialAsciiDevice  # noqa: E402
from sim_fixtures.world import Noise  # noqa: E402

TIMEOUT_S = 0.5


def serial_port(link: Path, baudrate: int) -> serial.Serial:
    return serial.serial_for_url(str(link), do_not_open=True, baudrate=baudrate, timeout=TIMEOUT_S)


def wire_ms(frame_bytes: int, baudrate: int) -> float:
    """Time ``frame_bytes`` take on a serial line at ``baudrate`` (8N1: 10 bits a byte), ms."""
    return frame_bytes * 10 / baudrate * 1e3


def setups(tmp: Path, stack: ExitStack):
    """(name, driver, wire_ms) for each driver, its simulated device started on ``stack``."""
    rng = np.random.default_rng(0)
    length, dial = Noise().drawstring(rng), Noise().dial(rng)
    regs = RegisterMap()
    for dialect in ("sylvac", "mitutoyo"):
        link = tmp / f"dial-{dialect}"
        stack.enter_context(SerialAsciiDevice(link, DIALECTS[dialect], lambda: dial.measure(0.1)))
        frame = len(DIALECTS[dialect].request) + len(DIALECTS[dialect].reply(0.1))
        yield (
            f"dial ({dialect}, serial 9600 Bd)",
            DialIndicator(serial_port(link, 9600), dialect),
            wire_ms(frame, 9600),
        )
    link = tmp / "drawstring-ascii"
    stack.enter_context(SerialAsciiDevice(link, DIALECTS["drawstring"], lambda: length.measure(900.0)))
    frame = len(DIALECTS["drawstring"].request) + len(DIALECTS["drawstring"].reply(900.0))
    yield (
        "drawstring (ASCII, serial 115200 Bd)",
        AsciiDrawstring(serial_port(link, 115200)),
        wire_ms(frame, 115200),
    )
    tcp = stack.enter_context(ModbusDevice(regs, lambda: length.measure(900.0), tcp=("127.0.0.1", 0)))
    client = ModbusTcpClient("127.0.0.1", port=tcp.address["port"], timeout=TIMEOUT_S, retries=0)
    yield "drawstring (Modbus TCP)", ModbusDrawstring(client, regs), 0.0
    link = tmp / "drawstring-rtu"
    stack.enter_context(ModbusDevice(regs, lambda: length.measure(900.0), rtu_link=link))
    client = ModbusSerialClient(str(link), baudrate=115200, timeout=TIMEOUT_S, retries=0)
    # request 8 bytes, reply 9 bytes, plus the 3.5-character silences that end RTU frames
    yield "drawstring (Modbus RTU, 115200 Bd)", ModbusDrawstring(client, regs), wire_ms(24, 115200)


def latencies_ms(driver, reads: int) -> np.ndarray:
    """Wall time of each ``read()``, ms, after 20 warm-up reads."""
    with driver:
        for _ in range(20):
            driver.read()
        out = np.empty(reads)
        for i in range(reads):
            t0 = time.perf_counter()
            driver.read()
            out[i] = (time.perf_counter() - t0) * 1e3
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reads", type=int, default=2000)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp, ExitStack() as stack:
        for name, driver, wire in setups(Path(tmp), stack):
            ms = latencies_ms(driver, args.reads)
            p50, p99 = np.percentile(ms, [50, 99])
            results.append(
                {
                    "driver": name,
                    "reads": args.reads,
                    "p50_ms": round(p50, 3),
                    "p99_ms": round(p99, 3),
                    "reads_per_s": round(1e3 / ms.mean()),
                    "wire_ms": round(wire, 3),
                }
            )
            print(
                f"{name:38s} p50 {p50:6.3f} ms  p99 {p99:6.3f} ms  "
                f"{results[-1]['reads_per_s']:5d} reads/s  + wire {wire:5.2f} ms",
                flush=True,
            )
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
