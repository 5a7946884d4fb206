"""Robot joint sources against their simulated controllers, through the real client libraries
(ur_rtde's RTDEReceiveInterface; pymodbus's ModbusTcpClient), faults included; the joint registers'
frames byte-exact on a pty."""

import os
import signal
import socket
import threading
import time

import numpy as np
import pytest
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.base import (
    Backoff,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    call_with_reconnect,
)
from drivers.robot import JointRegisterMap, ModbusJointSource, RtdeJointSource
from sim_fixtures.modbus_joints import ModbusJointServer, robot_joints
from sim_fixtures.robot_program import IDLE, RUNNING, RobotFault, SimRobot
from sim_fixtures.rtde_server import start_on_free_loopback
from tests.system.serial_script import ScriptedSerial

TARGETS = [[0.0, -50.0, -20.0, 0.0, -90.0, 0.0], [20.0, -40.0, -30.0, 5.0, -80.0, 10.0]]
RTDE_UNITS = {
    "q_deg": "deg",
    "qd_deg_s": "deg/s",
    "robot_mode": "",
    "controller_time_s": "s",
    "package_age_s": "s",
}
QUICK = Backoff(attempts=4, initial_s=0.05, max_s=0.2)


def make_robot(**kw):
    return SimRobot(TARGETS, speed_deg_s=40.0, accel_deg_s2=80.0, dwell_s=0.3, **kw)


def read_until(driver, error, timeout_s, tolerate=()):
    """Read until ``driver.read()`` raises ``error`` (returned), failing after ``timeout_s``;
    errors in ``tolerate`` are expected on the way."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            driver.read()
        except error as exc:
            return exc
        except tolerate:
            pass
        time.sleep(0.01)
    pytest.fail(f"{driver.name} kept reading for {timeout_s} s, expected {error.__name__}")


# --- RTDE -----------------------------------------------------------------------------------


@pytest.fixture
def rtde_server():
    srv = start_on_free_loopback(make_robot())
    yield srv
    srv.stop()


def test_rtde_reads_joints_in_degrees_as_simulated(rtde_server):
    robot = make_robot()
    with RtdeJointSource(rtde_server.host, 500.0) as source:
        assert set(source.describe()) == set(RTDE_UNITS)
        states, deadline = set(), time.monotonic() + 6.0
        while states != {True, False} and time.monotonic() < deadline:
            reading = source.read()
            truth = robot.state(reading.values["controller_time_s"])
            np.testing.assert_allclose(reading.values["q_deg"], truth.q_deg, atol=1e-9)
            np.testing.assert_allclose(reading.values["qd_deg_s"], truth.qd_deg_s, atol=1e-9)
            assert reading.values["robot_mode"] == RUNNING
            states.add(truth.dwelling)
            time.sleep(0.03)
    assert states == {True, False}
    assert reading.units == RTDE_UNITS
    assert reading.device == "robot" and abs(reading.t_wall - time.time()) < 5


def test_rtde_reports_a_robot_that_is_not_running():
    robot = make_robot(faults=[RobotFault(start_s=0.0, end_s=1e6, robot_mode=IDLE)])
    with start_on_free_loopback(robot) as srv, RtdeJointSource(srv.host) as source:
        reading = source.read()
    assert reading.values["robot_mode"] == IDLE
    np.testing.assert_allclose(reading.values["q_deg"], TARGETS[0], atol=1e-9)


def test_rtde_controller_goes_away_and_comes_back(rtde_server):
    source = RtdeJointSource(rtde_server.host)
    with source:
        source.read()
        rtde_server.stop()
        exc = read_until(source, DeviceUnreachable, timeout_s=3.0)
        assert str(exc).startswith("robot: ") and "connection lost" in str(exc)
        with pytest.raises(
            DeviceUnreachable,
            match=r"unreachable after 2 attempts \(cannot "
            r"connect to RTDE",
        ):
            call_with_reconnect(source, source.read, Backoff(attempts=2, initial_s=0.01))
        rtde_server.start()
        reading = call_with_reconnect(source, source.read, QUICK)
        assert reading.values["robot_mode"] == RUNNING


def test_rtde_silent_controller_times_out_and_the_link_drops(rtde_server):
    source = RtdeJointSource(rtde_server.host, stale_s=0.3)
    source.open()
    try:
        source.read()
        os.kill(rtde_server.pid, signal.SIGSTOP)  # controller freezes, socket stays open
        exc = read_until(source, DeviceTimeout, timeout_s=2.0)
        assert "no new data package from RTDE" in str(exc)
        # ur_rtde's own 2.5 s read deadline then drops the link
        read_until(source, DeviceUnreachable, timeout_s=4.0, tolerate=DeviceTimeout)
    finally:
        os.kill(rtde_server.pid, signal.SIGCONT)
        source.close()


@pytest.fixture
def mute_listener():
    """Accepts TCP on 127.0.0.x:30004 and never answers (a hung controller)."""
    for last in range(251, 255):
        try:
            sock = socket.create_server((f"127.0.0.{last}", 30004))
            break
        except OSError:
            continue
    else:
        pytest.skip("no free loopback address for the mute listener")
    accepted = []
    stop = threading.Event()

    def accept():
        sock.settimeout(0.05)
        while not stop.is_set():
            try:
                accepted.append(sock.accept()[0])
            except TimeoutError:
                pass

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    yield sock.getsockname()[0]
    stop.set()
    thread.join(2.0)
    for conn in accepted:
        conn.close()
    sock.close()


def test_rtde_hung_controller_fails_the_probe_within_its_timeout(mute_listener):
    source = RtdeJointSource(mute_listener, probe_timeout_s=0.3)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match=r"robot: RTDE .* did not answer .* within 0.3 s"):
        source.open()
    assert time.monotonic() - t0 < 2.0


def test_rtde_refuses_bad_frequency_and_read_before_open():
    with pytest.raises(ValueError, match="frequency_hz"):
        RtdeJointSource("127.0.0.1", 1000.0)
    with pytest.raises(
        DeviceUnreachable,
        match=r"robot: RTDE 127.0.0.1:30004 not connected "
        r"\(open\(\) first\)",
    ):
        RtdeJointSource("127.0.0.1").read()


# --- Modbus TCP joint registers -------------------------------------------------------------


def test_joint_registers_layout_int32_millidegrees_high_word_first():
    regs = JointRegisterMap()
    words = regs.encode_deg([1.5, -2.25, 0.0, 90.0, -180.0, 0.001])
    assert words == [0x0000, 0x05DC, 0xFFFF, 0xF736, 0, 0, 0x0001, 0x5F90, 0xFFFD, 0x40E0, 0x0000, 0x0001]
    assert regs.count == 12
    assert regs.decode_deg(words) == pytest.approx((1.5, -2.25, 0.0, 90.0, -180.0, 0.001))


@pytest.mark.parametrize("encoding", ["int32_mdeg", "float32_deg"])
@pytest.mark.parametrize("word_order", ["big", "little"])
def test_joint_registers_round_trip(encoding, word_order):
    regs = JointRegisterMap(encoding=encoding, word_order=word_order, scale=2.0)
    q = (12.346, -170.0, 0.5, 33.25, -0.002, 179.998)
    assert regs.decode_deg(regs.encode_deg(q)) == pytest.approx(q, abs=1e-3)
    with pytest.raises(ValueError, match="encoding"):
        JointRegisterMap(encoding="int16")


def test_joint_registers_read_byte_exact_over_the_modbus_driver(tmp_path):
    # The drawstring's Modbus driver, joints in its layout: 12 holding registers at 100 of device 3
    # (RTU frames: id, function, data, CRC-16 low byte first), six INT32 millidegrees back.
    request = bytes.fromhex("03 03 00 64 00 0c 05 f2")
    reply = bytes.fromhex(
        "03 03 18 00 00 05 dc ff ff f7 36 00 00 00 00 00 01 5f 90 ff fd 40 e0 00 00 00 01 ee ba"
    )
    client = ModbusSerialClient(str(tmp_path / "ctl"), baudrate=115200, timeout=0.3, retries=0)
    with ScriptedSerial(tmp_path / "ctl", [(request, reply)]) as dev:
        with ModbusJointSource(client, JointRegisterMap(address=100, device_id=3)) as source:
            reading = source.read()
    assert dev.received == [request]
    assert reading.values["q_deg"] == pytest.approx((1.5, -2.25, 0.0, 90.0, -180.0, 0.001), abs=1e-9)
    assert reading.units == {"q_deg": "deg"}


def held_joint_server(port=0):
    regs = JointRegisterMap(address=100, device_id=3)
    return ModbusJointServer(regs, robot_joints(make_robot(hold=True)), tcp=("127.0.0.1", port))


@pytest.fixture
def modbus_robot():
    server = held_joint_server()
    server.start()
    yield server
    server.stop()


def modbus_source(server, retries=0):
    client = ModbusTcpClient(
        server.address["host"], port=server.address["port"], timeout=0.3, retries=retries
    )
    return ModbusJointSource(client, server.registers)


def test_modbus_reads_the_simulated_controllers_joints(modbus_robot):
    with modbus_source(modbus_robot) as source:
        reading = source.read()
    assert source.describe()["q_deg"].shape == (6,)
    assert reading.units == {"q_deg": "deg"}
    np.testing.assert_allclose(reading.values["q_deg"], TARGETS[0], atol=5e-4)
    assert modbus_robot.requests == 1


@pytest.mark.parametrize(
    "fault, error, match",
    [
        ("error", DeviceReplyError, "Modbus exception code 4 reading joint registers 100..111"),
        ("silence", DeviceTimeout, "no reply from 127.0.0.1"),
        ("unplug", DeviceUnreachable, "link lost"),
    ],
)
def test_modbus_faults_are_named_then_reconnect_reads(modbus_robot, fault, error, match):
    with modbus_source(modbus_robot) as source:
        modbus_robot.faults.inject(fault)
        with pytest.raises(error, match=f"robot: .*{match}"):
            source.read()
        reading = call_with_reconnect(source, source.read, QUICK)
    np.testing.assert_allclose(reading.values["q_deg"], TARGETS[0], atol=5e-4)


def test_modbus_controller_goes_away_and_comes_back():
    gone = held_joint_server()
    gone.start()
    with modbus_source(gone) as source:
        source.read()
        gone.stop()
        with pytest.raises(DeviceUnreachable, match="robot: unreachable after 2 attempts"):
            call_with_reconnect(source, source.read, Backoff(attempts=2, initial_s=0.01))
        back = held_joint_server(port=gone.address["port"])
        back.start()
        try:
            reading = call_with_reconnect(source, source.read, QUICK)
        finally:
            back.stop()
    np.testing.assert_allclose(reading.values["q_deg"], TARGETS[0], atol=5e-4)
