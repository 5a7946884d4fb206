"""Benchmark: read the robot over RTDE at 500 Hz without dropped packages while the drawstring
(Modbus TCP) and the dial (serial ASCII on a pty) are polled at >= 50 Hz each.

The simulated controller runs in its own process (as ur_rtde requires) on a free 127.0.0.x; the
simulated drawstring and dial run as threads in this process, like the drivers polling them.
Every data package carries the controller timestamp (period 1/f): the distinct timestamps the
driver sees, and the gaps between them, count the packages dropped anywhere (server late,
client skipped, poll loop too slow); the server counts the ones it skipped itself.
Latencies, p50/p99 in ms:

- RTDE ``read()``: one call of the driver (ur_rtde answers from its receive thread's copy);
- RTDE age: from the package's scheduled send time to the moment the driver first sees it;
- drawstring / dial ``read()``: one request/reply round trip to the simulated device.

Run from the repository root:
    /tmp/venv/bin/python benchmarks/rtde_rate.py [--seconds 10] [--frequency 500] [--poll-hz 50]
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import serial
from pymodbus.client import ModbusTcpClient

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.ascii import DIALECTS  # noqa: E402
from drivers.dial import DialIndicator  # noqa: E402
from drivers.drawstring import ModbusDrawstring, RegisterMap  # noqa: E402
from drivers.robot import RtdeJointSource  # noqa: E402
from sim_fixtures.modbus_device import ModbusDevice  # noqa: E402
from sim_fixtures.robot_program import SimRobot  # noqa: E402
from sim_fixtures.rtde_server import start_on_free_loopback  # noqa: E402
from sim_fixtures.serial_device import SerialAsciiDevice  # noqa: E402
from sim_fixtures.world import Noise  # noqa: E402

PLAN_DEG = [[0.0, -50.0, -20.0, 0.0, -90.0, 0.0], [20.0, -40.0, -30.0, 5.0, -80.0, 10.0]]


def percentiles_ms(samples_s) -> str:
    """``p50 / p99`` of durations given in seconds, as milliseconds."""
    if len(samples_s) == 0:
        return "n/a"
    p50, p99 = np.percentile(np.asarray(samples_s) * 1e3, [50, 99])
    return f"p50 {p50:7.3f} ms   p99 {p99:7.3f} ms"


def dropped(stamps_s: list[float], frequency_hz: float) -> tuple[int, int]:
    """Packages missing between consecutive distinct timestamps, and the largest gap (periods)."""
    if len(stamps_s) < 2:
        return 0, 0
    periods = np.rint(np.diff(stamps_s) * frequency_hz).astype(int)
    return int(np.sum(np.maximum(periods - 1, 0))), int(periods.max())


@contextlib.contextmanager
def polled_instruments(tmp: Path, rng: np.random.Generator):
    """Simulated drawstring (Modbus TCP) and dial (Sylvac on a pty) with drivers open on them."""
    drawstring_noise, dial_noise = Noise().drawstring(rng), Noise().dial(rng)
    regs = RegisterMap()
    with (
        ModbusDevice(regs, lambda: drawstring_noise.measure(1234.5), tcp=("127.0.0.1", 0)) as ds_dev,
        SerialAsciiDevice(tmp / "dial", DIALECTS["sylvac"], lambda: dial_noise.measure(0.25)),
    ):
        client = ModbusTcpClient("127.0.0.1", port=ds_dev.address["port"], timeout=0.3, retries=0)
        port = serial.serial_for_url(str(tmp / "dial"), do_not_open=True, timeout=0.2)
        with ModbusDrawstring(client, regs) as drawstring, DialIndicator(port, "sylvac") as dial:
            yield [drawstring, dial]


def poll(driver, hz: float, stop: threading.Event, latencies: list, errors: list) -> None:
    """Read ``driver`` every 1/hz s (absolute schedule) until ``stop``; record each read's time."""
    period, next_t = 1.0 / hz, time.monotonic()
    while not stop.is_set():
        t0 = time.monotonic()
        try:
            driver.read()
        except Exception as exc:  # noqa: BLE001 -- a benchmark counts failures, it does not stop
            errors.append(repr(exc))
        latencies.append(time.monotonic() - t0)
        next_t += period
        stop.wait(max(0.0, next_t - time.monotonic()))


def read_robot(source: RtdeJointSource, start: float, seconds: float) -> dict:
    """Poll the RTDE source for ``seconds`` (faster than the stream, to see every package)."""
    stamps, ages, calls = [], [], []
    t_end = time.monotonic() + seconds
    last = None
    while time.monotonic() < t_end:
        t0 = time.monotonic()
        reading = source.read()
        t1 = time.monotonic()
        calls.append(t1 - t0)
        stamp = reading.values["controller_time_s"]
        if stamp != last:
            stamps.append(stamp)
            ages.append((t1 - start) - stamp)
            last = stamp
        time.sleep(0.0002)
    return {"stamps": stamps, "ages": ages, "calls": calls}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--frequency", type=float, default=500.0, help="RTDE rate, Hz")
    parser.add_argument("--poll-hz", type=float, default=50.0, help="drawstring and dial rate")
    args = parser.parse_args(argv)

    robot = SimRobot(PLAN_DEG, speed_deg_s=30.0, accel_deg_s2=60.0, dwell_s=1.0)
    start = time.monotonic()
    stop = threading.Event()
    with (
        tempfile.TemporaryDirectory() as tmp,
        start_on_free_loopback(robot, start_monotonic=start) as server,
        RtdeJointSource(server.host, args.frequency) as source,
        polled_instruments(Path(tmp), np.random.default_rng(4)) as others,
    ):
        lat = {d.name: [] for d in others}
        errs = {d.name: [] for d in others}
        threads = [
            threading.Thread(target=poll, args=(d, args.poll_hz, stop, lat[d.name], errs[d.name]))
            for d in others
        ]
        for t in threads:
            t.start()
        try:
            robot_stats = read_robot(source, start, args.seconds)
        finally:
            stop.set()
            for t in threads:
                t.join(5.0)

    stamps = robot_stats["stamps"]
    drops, worst = dropped(stamps, args.frequency)
    expected = int(round((stamps[-1] - stamps[0]) * args.frequency)) + 1 if stamps else 0
    print(
        f"RTDE {server.host}:30004 at {args.frequency:g} Hz for {args.seconds:g} s "
        f"(drawstring + dial polled at {args.poll_hz:g} Hz each)"
    )
    print(
        f"  packages seen {len(stamps)} of {expected}; dropped {drops} "
        f"(server late: {server.skipped}, client missed: {drops - server.skipped}); "
        f"largest gap {worst} period(s)"
    )
    print(f"  RTDE read()      {percentiles_ms(robot_stats['calls'])}")
    print(f"  RTDE age         {percentiles_ms(robot_stats['ages'])}")
    for name, samples in lat.items():
        rate = len(samples) / args.seconds
        print(f"  {name:10s} read() {percentiles_ms(samples)}   {rate:5.1f} Hz, {len(errs[name])} errors")
    return 0 if drops == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
