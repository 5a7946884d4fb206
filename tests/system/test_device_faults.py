"""The fault-injecting harness at the device boundary: simulated devices that answer with values
that are no numbers, stray replies, floods, late or garbage packages and stalled handshakes, read
through the real client libraries (pymodbus TCP and RTU, pyserial on a pty, ur_rtde). Whatever
they send, a driver gives a finite reading or a named, retryable error with a bounded message."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.base import (
    EXCERPT_CHARS,
    Backoff,
    DeviceTimeout,
    GarbledReply,
    IncompatibleDevice,
    call_with_reconnect,
)
from drivers.drawstring import AsciiDrawstring, ModbusDrawstring, RegisterMap
from drivers.robot import RtdeJointSource
from sim_fixtures.modbus_device import ModbusDevice
from sim_fixtures.robot_program import SimRobot
from sim_fixtures.rtde_server import RtdeFaults, start_on_free_loopback
from sim_fixtures.serial_device import PtyPort

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT_S = 0.3
TRUE_MM = 1234.5
FLOAT_MAP = RegisterMap(address=4, encoding="float32_mm", device_id=2)
TARGETS = [[0.0, -50.0, -20.0, 0.0, -90.0, 0.0], [20.0, -40.0, -30.0, 5.0, -80.0, 10.0]]


@pytest.fixture(params=["tcp", "rtu"])
def float_sensor(request, tmp_path):
    """A drawstring publishing FLOAT32 mm (a NaN is expressible) over Modbus TCP or RTU."""
    transport = {"tcp": ("127.0.0.1", 0)} if request.param == "tcp" else {"rtu_link": tmp_path / "ds"}
    with ModbusDevice(FLOAT_MAP, lambda: TRUE_MM, **transport) as dev:
        if request.param == "tcp":
            client = ModbusTcpClient("127.0.0.1", port=dev.address["port"], timeout=TIMEOUT_S, retries=0)
        else:
            client = ModbusSerialClient(dev.address["port"], baudrate=115200, timeout=TIMEOUT_S, retries=0)
        yield dev, ModbusDrawstring(client, FLOAT_MAP)


@pytest.mark.parametrize("fault", ["nan", "inf"])
def test_a_float_register_holding_no_number_is_a_retryable_error_never_a_reading(float_sensor, fault):
    dev, ds = float_sensor
    dev.faults.every(fault, 7)
    refused = []
    with ds:
        for _ in range(30):
            try:
                assert ds.read().values["length_mm"] == TRUE_MM
            except GarbledReply as exc:
                refused.append(str(exc))
    assert len(refused) == 30 // 7
    assert refused[0] == f"drawstring: length register 4..5 hold no number ({fault})"


def test_a_reply_to_another_transaction_is_named_and_retried(float_sensor):
    dev, ds = float_sensor
    dev.faults.inject("stray")
    with ds:
        with pytest.raises(GarbledReply) as caught:
            ds.read()
        assert (
            call_with_reconnect(ds, ds.read, Backoff(attempts=3, initial_s=0.01)).values["length_mm"]
            == TRUE_MM
        )
    said = str(caught.value)
    assert "unparseable" not in said
    if dev.cable:
        assert said.startswith(
            "drawstring: a reply from device id 3, not 2: another device answered: 03 03 04"
        )
    else:
        assert said.startswith("drawstring: a reply to transaction ")
        assert ": a late reply or another client: " in said


def test_a_device_flooding_bytes_without_a_terminator_gives_a_short_message(tmp_path):
    """A serial drawstring that streams 50 KB of digits and never ends a line: the read ends at the
    longest reply a drawstring can send, and the message shows 80 characters and the size."""
    port = PtyPort(tmp_path / "flood")
    stop = threading.Event()

    def flood():
        while not stop.is_set():
            try:
                os.write(port.master, b"7" * 4096)
            except OSError:
                return
            time.sleep(0.001)

    thread = threading.Thread(target=flood, daemon=True)
    thread.start()
    try:
        ds = AsciiDrawstring(serial.serial_for_url(str(port.link), do_not_open=True, timeout=TIMEOUT_S))
        with ds, pytest.raises(GarbledReply) as caught:
            ds.read()
    finally:
        stop.set()
        thread.join(1.0)
        port.unplug()
    said = str(caught.value)
    assert said.startswith("drawstring: no terminator in b'7777") and said.endswith(
        "... (256 bytes): the device floods bytes"
    )
    assert len(said) < EXCERPT_CHARS + 80


# --- RTDE -----------------------------------------------------------------------------------


def rtde(faults: RtdeFaults):
    robot = SimRobot(TARGETS, speed_deg_s=40.0, accel_deg_s2=80.0, dwell_s=0.3)
    return start_on_free_loopback(robot, faults=faults)


@pytest.mark.parametrize(
    "stall_at, step",
    [
        ("v", "the controller version request"),
        ("O", "the output recipe request"),
        ("S", "the start request"),
        ("U", "a data package after start"),
    ],
)
def test_a_controller_stalling_in_the_handshake_fails_open_within_the_probe_timeout(stall_at, step, capfd):
    server = rtde(RtdeFaults(stall_at=stall_at))
    try:
        source = RtdeJointSource(server.host, probe_timeout_s=0.3)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=f"^robot: RTDE .*:30004 did not answer {step} within 0.3 s$"):
            source.open()
        assert time.monotonic() - t0 < 1.5
        source.close()
    finally:
        server.stop()
    assert "boost" not in capfd.readouterr().err  # ur_rtde never got to try


def test_a_recipe_typing_actual_q_otherwise_is_refused():
    server = rtde(RtdeFaults(types=(("actual_q", "VECTOR3D"),)))
    try:
        with pytest.raises(
            IncompatibleDevice, match="types actual_q as VECTOR3D, not VECTOR6D: not a UR controller"
        ):
            RtdeJointSource(server.host, probe_timeout_s=0.5).open()
    finally:
        server.stop()


def test_a_garbage_data_package_is_refused_with_its_size():
    server = rtde(RtdeFaults(garbage=True))
    try:
        with pytest.raises(GarbledReply, match=r"sent a data package of 65535 bytes, the recipe makes 112$"):
            RtdeJointSource(server.host, probe_timeout_s=0.5).open()
    finally:
        server.stop()


def read_many(source, n: int) -> tuple[list, list[str]]:
    readings, refused = [], []
    while len(readings) + len(refused) < n:
        try:
            readings.append(source.read())
        except GarbledReply as exc:
            refused.append(str(exc))
        time.sleep(0.004)
    return readings, refused


def test_packages_with_nan_joints_are_refused_never_read():
    server = rtde(RtdeFaults(nan_every=5))
    try:
        with RtdeJointSource(server.host, probe_timeout_s=0.5) as source:
            readings, refused = read_many(source, 100)
    finally:
        server.stop()
    assert refused and refused[0].startswith("robot: RTDE ") and "no robot state (joints [nan" in refused[0]
    assert all(np.all(np.isfinite(r.values["q_deg"])) for r in readings)


def test_a_late_package_reads_as_late():
    """Every 10th package carries the state 0.2 s old (a stream that fell behind): its reading
    says so in ``package_age_s``; the others are current."""
    server = rtde(RtdeFaults(late_every=10, late_s=0.2))
    try:
        with RtdeJointSource(server.host, probe_timeout_s=0.5) as source:
            readings, _ = read_many(source, 300)
    finally:
        server.stop()
    age = np.array([r.values["package_age_s"] for r in readings])
    assert np.median(age) < 0.01
    assert 0.15 < age.max() < 0.3
    assert math.isfinite(age.sum())


def station_read(
    tmp_path, robot_host: str, drawstring_port: int
) -> tuple[subprocess.CompletedProcess, float]:
    """`station read` on a config with the RTDE robot at ``robot_host`` and a FLOAT32 drawstring
    at 127.0.0.1:``drawstring_port`` (no dial); the result and how long it took (s)."""
    config = tmp_path / "station.toml"
    config.write_text(
        f'[robot]\nkind = "rtde"\nhost = "{robot_host}"\n\n'
        f'[drawstring]\nkind = "modbus_tcp"\nhost = "127.0.0.1"\nport = {drawstring_port}\ndevice_id = 2\n\n'
        '[drawstring.registers]\naddress = 4\nencoding = "float32_mm"\n'
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "station.cli", "read", "--config", str(config)],
        capture_output=True, text=True, timeout=120, env=env, cwd=tmp_path,
    )  # fmt: skip
    return proc, time.monotonic() - t0


def test_station_read_refuses_a_controller_stalled_in_its_handshake_in_one_line(tmp_path):
    server = rtde(RtdeFaults(stall_at="O"))
    try:
        proc, took_s = station_read(tmp_path, server.host, 1)
    finally:
        server.stop()
    assert proc.returncode == 1, proc.stderr
    assert proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "did not answer the output recipe request" in lines[0], proc.stderr
    assert took_s < 30


def test_station_read_of_a_drawstring_holding_nan_prints_valid_json_or_refuses(tmp_path):
    """Every 2nd reply NaN: the retries read a number and the JSON holds it; every reply NaN: a
    one-line refusal, exit 1; never bare NaN on stdout."""
    server = rtde(RtdeFaults())
    try:
        for every, code in ((2, 0), (1, 1)):
            with ModbusDevice(FLOAT_MAP, lambda: TRUE_MM, tcp=("127.0.0.1", 0)) as dev:
                dev.faults.every("nan", every)
                dev.faults.inject("nan")
                proc, _ = station_read(tmp_path, server.host, dev.address["port"])
            assert proc.returncode == code, proc.stderr
            if code == 0:
                assert json.loads(proc.stdout, parse_constant=pytest.fail)["length_mm"] == TRUE_MM
            else:
                assert proc.stdout == ""
                assert "length register 4..5 hold no number (nan)" in proc.stderr
                assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    finally:
        server.stop()


def test_station_read_refuses_a_recipe_of_other_types_in_one_line(tmp_path):
    """Issue 21: `actual_q` typed VECTOR3D once read as joints ending in zeros, exit 0."""
    server = rtde(RtdeFaults(types=(("actual_q", "VECTOR3D"),)))
    try:
        proc, _ = station_read(tmp_path, server.host, 1)
    finally:
        server.stop()
    assert proc.returncode == 1 and proc.stdout == ""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "types actual_q as VECTOR3D, not VECTOR6D" in lines[0], proc.stderr
