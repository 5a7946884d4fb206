"""Corrected targets handed to a running program: the real ``ur_rtde`` RTDEIOInterface writes the
RTDE input registers of the simulated controller, which hands them to its program; the simulated
OPC UA server takes them in writable nodes, the simulated rosbridge on a topic (``roslibpy``
publishing); what a cell gets wrong (another client holding the registers, nodes the server lacks,
a recipe of other types, no target topic) leaves no channel, said by name. A controller that goes
away or freezes with the channel open costs the station a reconnect, not its process."""

import json
import os
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.base import DeviceUnreachable
from drivers.opcua import OpcUaJointSource
from drivers.robot import TARGET_INDEX_INPUT, RtdeJointSource
from drivers.ros import RosJointSource
from sim_fixtures import rtde_wire as wire
from sim_fixtures.opcua_server import TARGET_INDEX_NODE, OpcUaRobotServer, position_node, target_node
from sim_fixtures.robot_program import RUNNING, SimRobot
from sim_fixtures.rosbridge_server import JOINT_NAMES, RosbridgeServer
from sim_fixtures.rtde_server import start_on_free_loopback
from sim_fixtures.sources import SimClock
from sim_fixtures.target_channel import TargetChannel, TargetInbox
from tests.system.channel_client import Q0, Q1
from tests.system.moving import free_address
from tests.system.test_rtde_server import RawClient

ROOT = Path(__file__).resolve().parents[2]

TARGETS = [[0.0, -50.0, -20.0, 0.0, -90.0, 0.0], [20.0, -40.0, -30.0, 5.0, -80.0, 10.0]]
CORRECTED = [20.31, -39.87, -30.12, 5.21, -80.33, 10.47]  # target 1 a few tenths of a degree away


@pytest.fixture
def controller():
    """A simulated UR controller whose program's channel records what its registers hand it."""
    robot = SimRobot(TARGETS, speed_deg_s=40.0, accel_deg_s2=80.0, dwell_s=0.3, hold=True)
    channel, clock = TargetChannel(), SimClock()
    server = start_on_free_loopback(
        robot, start_monotonic=clock.start_monotonic, inbox=TargetInbox(channel, robot, clock)
    )
    yield server, channel
    server.stop()


def _held(channel: TargetChannel, timeout_s: float = 2.0):
    """What the channel holds once something arrived (the server is another process)."""
    deadline = time.monotonic() + timeout_s
    while (held := channel.at(1e12)) is None and time.monotonic() < deadline:
        time.sleep(0.01)
    return held


def test_ur_rtde_writes_the_target_registers_and_the_program_gets_the_target(controller):
    server, channel = controller
    with RtdeJointSource(server.host) as robot:
        targets = robot.target_channel()
        assert targets is not None and "int 42: index + 1" in targets.where
        time.sleep(0.2)
        assert channel.at(1e12) is None  # opening the channel names no target (0 in the index)
        targets.write(1, CORRECTED)
        held = _held(channel)
        assert held is not None and held[0] == 1
        np.testing.assert_allclose(held[1][:5], CORRECTED[:5], atol=1e-9)  # doubles, rad on the wire
        np.testing.assert_allclose(held[1][5], CORRECTED[5], atol=1e-4)  # joint 6: 1 urad steps
        assert robot.read().values["q_deg"] == pytest.approx(TARGETS[0])  # the stream goes on beside it
    assert server.input_errors == 0


def _client(host: str, mode: str) -> subprocess.Popen:
    """``tests.system.channel_client`` against ``host``, once it has opened the channel."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.system.channel_client", host, mode],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _until(proc, "open")
    return proc


def _until(proc: subprocess.Popen, line: str) -> None:
    """Read the client's stdout up to ``line`` (ur_rtde prints there too)."""
    while (got := proc.stdout.readline()) != f"{line}\n":
        if not got:
            out, err = proc.communicate(timeout=10)
            pytest.fail(f"the client ended (exit {proc.returncode}) before {line!r}:\n{out}{err[-2000:]}")


def _said(proc: subprocess.Popen, timeout_s: float, what: str) -> dict:
    """The client's last line (JSON) once it exits 0 within ``timeout_s``: else it failed ``what``."""
    try:
        out, err = proc.communicate("\n", timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the station's process hung {what} ({timeout_s} s):\n{err[-2000:]}")
    assert proc.returncode == 0, f"the station's process died {what} (exit {proc.returncode}):\n{err[-2000:]}"
    return json.loads([line for line in out.splitlines() if line.startswith("{")][-1])


@pytest.mark.guard  # issue 33: the guard tier runs it too
def test_a_controller_gone_with_the_channel_open_costs_a_reconnect_not_the_process(controller):
    """A controller reboot with the target channel open (ur_rtde's RTDEIOInterface): the link is
    lost, a write says so, the reconnect closes the dead channel, reads again and the channel comes
    back. ur_rtde's IO interface aborts the process that drops it once its controller has gone
    (its destructor's pause request throws: std::terminate, "write: Broken pipe"): the client runs
    in a process of its own so that such an abort fails this test instead of ending pytest."""
    server, channel = controller
    proc = _client(server.host, "gone")
    try:
        held = _held(channel)
        assert held is not None and held[0] == 1
        np.testing.assert_allclose(held[1], Q1, atol=1e-4)
        server.stop()  # every connection closed: the receive link's and the registers'
        proc.stdin.write("gone\n")
        proc.stdin.flush()
        _until(proc, "lost")
        server.start()  # back, on the same address
        seen = _said(proc, 30.0, "when the controller went away with the target channel open")
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "connection lost" in seen["lost"]
    assert seen["write"].startswith(f"robot: RTDE {server.host}:30004: writing target 1: ")
    assert seen["robot_mode"] == RUNNING and seen["no_channel"] is None
    deadline = time.monotonic() + 2.0  # the server is another process
    while (held := channel.at(1e12))[0] != 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert held[0] == 0  # written through the channel the driver opened after the reconnect
    np.testing.assert_allclose(held[1], Q0, atol=1e-4)


def test_a_frozen_controller_with_the_channel_open_is_closed_within_seconds(controller):
    """A controller that freezes (SIGSTOP: its sockets stay open, nothing answers) with the channel
    open: closing the driver waits at most the channel's CLOSE_S and ur_rtde's 2.5 s read deadline
    (the IO interface's own disconnect waits for a pause reply for ever)."""
    server, _ = controller
    proc = _client(server.host, "frozen")
    os.kill(server.pid, signal.SIGSTOP)
    try:
        seen = _said(proc, 15.0, "closing a frozen controller's target channel")
    finally:
        os.kill(server.pid, signal.SIGCONT)
        if proc.poll() is None:
            proc.kill()
    assert "no new data package" in seen["silent"]
    assert seen["close_s"] < 4.5


def test_registers_another_client_writes_leave_no_channel_said_by_name(controller):
    server, _ = controller
    with RtdeJointSource(server.host) as first, RtdeJointSource(server.host) as second:
        assert first.target_channel() is not None
        assert second.target_channel() is None
        assert second.no_channel.startswith(f"RTDE {server.host}:30004 refused its input registers")
        assert "already in use" in second.no_channel


def test_an_input_recipe_has_the_controllers_types_and_a_package_of_another_size_is_dropped(controller):
    server, channel = controller
    client = RawClient(server.host)
    assert client.request(wire.REQUEST_PROTOCOL_VERSION, b"\x00\x02").payload == b"\x01"
    index = f"input_int_register_{TARGET_INDEX_INPUT}"
    refused = client.request(wire.SETUP_INPUTS, f"{index},input_double_register_42,joint_torque".encode())
    assert refused.payload == b"\x00INT32,DOUBLE,NOT_FOUND"
    setup = client.request(wire.SETUP_INPUTS, f"{index},input_double_register_42".encode())
    assert setup.payload == b"\x01INT32,DOUBLE"
    client.sock.sendall(wire.pack(wire.DATA_PACKAGE, struct.pack(">Bi", 1, 2)))  # the double missing
    client.sock.sendall(wire.pack(wire.DATA_PACKAGE, struct.pack(">Bid", 9, 2, 0.5)))  # no such recipe
    deadline = time.monotonic() + 2.0
    while server.input_errors < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert server.input_errors == 2 and channel.at(1e12) is None
    client.sock.sendall(wire.pack(wire.DATA_PACKAGE, struct.pack(">Bid", 1, 2, 0.5)))  # target 1
    held = _held(channel)
    assert held is not None and held[0] == 1 and held[1][0] == pytest.approx(np.degrees(0.5))
    client.sock.close()


def test_opcua_target_nodes_hand_the_program_its_target_and_missing_ones_leave_none():
    handed = []
    server = OpcUaRobotServer(
        lambda: (TARGETS[0], [0.0] * 6), *free_address(), hand=lambda k, q: handed.append((k, q))
    ).start()
    try:
        positions = [position_node(i) for i in range(1, 7)]
        targets = [target_node(i) for i in range(1, 7)]
        with OpcUaJointSource(
            server.url, positions, target_nodes=targets, target_index_node=TARGET_INDEX_NODE
        ) as s:
            channel = s.target_channel()
            assert channel is not None
            channel.write(1, CORRECTED)
            assert handed == [(1, pytest.approx(CORRECTED))]
        wrong = "ns=2;s=DeviceSet/Robot/TargetIndx"
        with OpcUaJointSource(server.url, positions, target_nodes=targets, target_index_node=wrong) as s:
            assert s.target_channel() is None
            assert s.no_channel == f"node {wrong}: BadNodeIdUnknown"
        with OpcUaJointSource(
            server.url, positions, target_nodes=positions, target_index_node=TARGET_INDEX_NODE
        ) as s:
            assert s.target_channel() is None  # the joints' own readings are not writable
            assert s.no_channel == f"node {positions[0]} is not writable"
    finally:
        server.stop()


def test_a_ros_target_topic_hands_the_program_its_target_and_none_configured_leaves_none():
    handed = []
    server = RosbridgeServer(
        lambda: (TARGETS[0], [0.0] * 6), *free_address(), hand=lambda k, q: handed.append((k, q))
    ).start()
    try:
        with RosJointSource(
            server.host, server.port, server.topic, JOINT_NAMES, target_topic=server.target_topic
        ) as s:
            channel = s.target_channel()
            assert channel is not None and channel.where.startswith(f"ROS topic {server.target_topic} on")
            channel.write(1, CORRECTED)
            deadline = time.monotonic() + 2.0
            while not handed and time.monotonic() < deadline:  # the bridge is another thread
                time.sleep(0.01)
            assert handed == [(1, pytest.approx(CORRECTED))]
        with RosJointSource(server.host, server.port, server.topic, JOINT_NAMES) as s:
            assert s.target_channel() is None and s.no_channel == "no [robot] target_topic"
    finally:
        server.stop()


def test_a_ros_bridge_gone_makes_a_target_write_fail_by_name():
    """The bridge goes away mid-session: the write says so (DeviceUnreachable, which the session's
    feed answers by correcting no more targets in-session), it does not vanish into a dead socket."""
    server = RosbridgeServer(lambda: (TARGETS[0], [0.0] * 6), *free_address()).start()
    source = RosJointSource(
        server.host, server.port, server.topic, JOINT_NAMES, target_topic="/station/target"
    )
    source.open()
    try:
        channel = source.target_channel()
        server.stop()
        deadline = time.monotonic() + 5.0
        while source._ros.is_connected and time.monotonic() < deadline:  # the close reaches roslibpy
            time.sleep(0.01)
        with pytest.raises(DeviceUnreachable, match=r"rosbridge ws://.* connection lost"):
            channel.write(1, CORRECTED)
    finally:
        source.close()
