"""The simulated RTDE controller: byte layouts, the protocol on a raw socket, and the real
``ur_rtde`` RTDEReceiveInterface against the server running in another process.

Byte layouts are written out from UR's RTDE guide (header ``>HB`` with the size counting the
header; V/S/P replies one ``uint8``; v four ``uint32``; O request ``double`` frequency + names,
reply ``uint8`` recipe id + type names; U ``uint8`` recipe id + packed values) and from what
ur_rtde 1.6 sends (``RTDE::negotiateProtocolVersion``: ``00 02``; ``sendOutputSetup``: names each
followed by a comma).
"""

import socket
import struct
import time

import numpy as np
import pytest
import rtde_receive

from sim_fixtures import rtde_wire as wire
from sim_fixtures.robot_program import RUNNING, SimRobot
from sim_fixtures.rtde_server import start_on_free_loopback

TARGETS = [[0.0, -50.0, -20.0, 0.0, -90.0, 0.0], [20.0, -40.0, -30.0, 5.0, -80.0, 10.0]]
VARIABLES = ["timestamp", "actual_q", "actual_qd", "robot_mode"]


def make_robot(hold=False):
    return SimRobot(TARGETS, speed_deg_s=40.0, accel_deg_s2=80.0, dwell_s=0.3, hold=hold)


@pytest.fixture
def server():
    srv = start_on_free_loopback(make_robot())
    yield srv
    srv.stop()


# --- byte layouts ---------------------------------------------------------------------------


def test_protocol_version_request_and_reply_bytes():
    request = bytes.fromhex("0005 56 0002")  # what ur_rtde sends: size 5, 'V', uint16 2
    (package,), rest = wire.split(request)
    assert package.kind == wire.REQUEST_PROTOCOL_VERSION and rest == b""
    assert wire.parse_protocol_request(package.payload) == 2
    assert wire.bool_reply(wire.REQUEST_PROTOCOL_VERSION, True) == bytes.fromhex("0004 56 01")
    assert wire.bool_reply(wire.START, False) == bytes.fromhex("0004 53 00")


def test_controller_version_reply_bytes():
    assert wire.version_reply(5, 12, 3, 1234) == bytes.fromhex("0013 76 00000005 0000000c 00000003 000004d2")


def test_setup_outputs_request_and_reply_bytes():
    payload = bytes.fromhex("407f400000000000") + b"timestamp,actual_q,"  # 500.0 Hz
    request = wire.pack(wire.SETUP_OUTPUTS, payload)
    assert request[:3] == struct.pack(">HB", 3 + 8 + 19, ord("O"))
    (package,), _ = wire.split(request)
    assert wire.parse_setup_outputs(package.payload) == (500.0, ["timestamp", "actual_q"])
    assert wire.setup_outputs_reply(1, ["DOUBLE", "VECTOR6D"]) == (
        bytes.fromhex("0013 4f 01") + b"DOUBLE,VECTOR6D"
    )


def test_output_types_are_the_controllers_and_unknown_names_are_not_found():
    assert wire.output_types(VARIABLES + ["joint_mode", "runtime_state", "no_such_thing"]) == [
        "DOUBLE",
        "VECTOR6D",
        "VECTOR6D",
        "INT32",
        "VECTOR6INT32",
        "UINT32",
        "NOT_FOUND",
    ]


def test_data_package_bytes_and_round_trip():
    types = ["DOUBLE", "INT32", "VECTOR6D"]
    fmt = wire.data_format(types)
    q = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    frame = wire.data_package(1, fmt, types, [0.5, 7, q])
    assert frame == bytes.fromhex(
        "0040 55 01"  # size 64, 'U', recipe 1
        "3fe0000000000000"  # timestamp 0.5
        "00000007"  # robot_mode 7
        "3ff0000000000000 4000000000000000 4008000000000000"
        "4010000000000000 4014000000000000 4018000000000000"
    )
    (package,), _ = wire.split(frame)
    assert wire.unpack_data(package.payload, fmt, types) == (1, {0: 0.5, 1: 7, 2: q})


def test_data_formats_of_integer_and_short_vector_types():
    fmt = wire.data_format(["UINT64", "UINT32", "VECTOR6INT32", "VECTOR3D"])
    assert fmt.size == 1 + 8 + 4 + 6 * 4 + 3 * 8
    with pytest.raises(wire.WireError, match="VECTOR6D needs 6"):
        wire.data_package(1, wire.data_format(["VECTOR6D"]), ["VECTOR6D"], [(1.0, 2.0)])
    with pytest.raises(wire.WireError, match="NOT_FOUND"):
        wire.data_format(["NOT_FOUND"])


def test_text_message_bytes():
    assert wire.text_message("hi", "s", 3) == bytes.fromhex("0009 4d 02") + b"hi" + bytes.fromhex(
        "01"
    ) + b"s" + bytes.fromhex("03")


def test_split_keeps_partial_packages_and_rejects_impossible_sizes():
    frame = wire.bool_reply(wire.START, True)
    packages, rest = wire.split(frame + frame[:2])
    assert len(packages) == 1 and rest == frame[:2]
    assert wire.split(rest + frame[2:]) == ([wire.Package(wire.START, b"\x01")], b"")
    with pytest.raises(wire.WireError, match="smaller than its 3-byte header"):
        wire.split(bytes.fromhex("0002 55"))


# --- the protocol on a raw socket -----------------------------------------------------------


class RawClient:
    """A minimal RTDE client on a plain socket, every wait bounded."""

    def __init__(self, host):
        self.sock = socket.create_connection((host, 30004), timeout=2.0)
        self.buffer = b""

    def request(self, kind, payload=b""):
        self.sock.sendall(wire.pack(kind, payload))
        return self.next_package()

    def next_package(self):
        while True:
            packages, rest = wire.split(self.buffer)
            if packages:
                self.buffer = self.buffer[wire.HEADER_SIZE + len(packages[0].payload) :]
                return packages[0]
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError("server closed")
            self.buffer += chunk

    def handshake(self, frequency, names):
        assert self.request(wire.REQUEST_PROTOCOL_VERSION, b"\x00\x02").payload == b"\x01"
        version = self.request(wire.GET_URCONTROL_VERSION)
        setup = self.request(
            wire.SETUP_OUTPUTS, struct.pack(">d", frequency) + (",".join(names) + ",").encode()
        )
        return version, setup


def test_handshake_replies_one_package_per_request_and_never_a_text_message(server):
    client = RawClient(server.host)
    version, setup = client.handshake(125.0, VARIABLES)
    assert version.kind == wire.GET_URCONTROL_VERSION
    assert struct.unpack(">IIII", version.payload)[0] == 5  # e-Series: ur_rtde picks 500 Hz
    assert setup.kind == wire.SETUP_OUTPUTS
    assert setup.payload == b"\x01DOUBLE,VECTOR6D,VECTOR6D,INT32"
    start = client.request(wire.START)
    assert (start.kind, start.payload) == (wire.START, b"\x01")
    client.sock.close()


def test_streams_at_the_recipe_frequency_then_pauses(server):
    client = RawClient(server.host)
    client.handshake(125.0, ["timestamp", "robot_mode"])
    assert client.request(wire.START).payload == b"\x01"
    fmt = wire.data_format(["DOUBLE", "INT32"])
    stamps, t_end = [], time.monotonic() + 1.0
    while time.monotonic() < t_end:
        package = client.next_package()
        assert package.kind == wire.DATA_PACKAGE
        _, values = wire.unpack_data(package.payload, fmt, ["DOUBLE", "INT32"])
        stamps.append(values[0])
        assert values[1] == RUNNING
    steps = np.diff(stamps)
    np.testing.assert_allclose(steps / 0.008, np.round(steps / 0.008), atol=1e-6)
    assert 100 <= len(stamps) <= 130  # 125 Hz for one second, loaded-machine slack
    client.sock.sendall(wire.pack(wire.PAUSE))
    while (reply := client.next_package()).kind == wire.DATA_PACKAGE:
        pass
    assert (reply.kind, reply.payload) == (wire.PAUSE, b"\x01")
    client.sock.settimeout(0.2)
    with pytest.raises(TimeoutError):
        client.sock.recv(1)  # nothing streams after the pause reply
    client.sock.close()


def test_refusals_unknown_version_and_start_without_recipe(server):
    client = RawClient(server.host)
    assert client.request(wire.REQUEST_PROTOCOL_VERSION, b"\x00\x01").payload == b"\x00"
    assert client.request(wire.START).payload == b"\x00"
    setup = client.request(wire.SETUP_OUTPUTS, struct.pack(">d", 500.0) + b"timestamp,nope,")
    assert setup.payload == b"\x01DOUBLE,NOT_FOUND"
    assert client.request(wire.START).payload == b"\x00"  # the recipe was not accepted
    client.sock.close()


def test_eof_mid_package_is_tolerated(server):
    half = socket.create_connection((server.host, 30004), timeout=2.0)
    half.sendall(b"\x00\x05")  # half a header, then hang up
    half.close()
    reset = socket.create_connection((server.host, 30004), timeout=2.0)
    reset.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    reset.close()  # RST instead of FIN
    client = RawClient(server.host)
    version, _ = client.handshake(500.0, ["timestamp"])
    assert version.kind == wire.GET_URCONTROL_VERSION and server.running
    client.sock.close()


# --- the real ur_rtde client ----------------------------------------------------------------


def test_ur_rtde_reads_the_held_robot_exactly():
    with start_on_free_loopback(make_robot(hold=True)) as srv:
        rtde = rtde_receive.RTDEReceiveInterface(srv.host, 500.0, VARIABLES)
        try:
            assert rtde.isConnected()
            np.testing.assert_allclose(np.degrees(rtde.getActualQ()), TARGETS[0], atol=1e-9)
            assert rtde.getActualQd() == [0.0] * 6 and rtde.getRobotMode() == RUNNING
            t0 = rtde.getTimestamp()
            time.sleep(0.1)
            assert 0.05 < rtde.getTimestamp() - t0 < 0.5
        finally:
            rtde.disconnect()


def test_ur_rtde_reads_the_moving_robot_as_simulated(server):
    robot = make_robot()
    rtde = rtde_receive.RTDEReceiveInterface(server.host, 500.0, VARIABLES)
    try:
        checked, seen, deadline = 0, set(), time.monotonic() + 6.0
        while (checked < 30 or seen != {True, False}) and time.monotonic() < deadline:
            t = rtde.getTimestamp()
            q, qd = rtde.getActualQ(), rtde.getActualQd()
            if rtde.getTimestamp() != t:
                continue  # a new package landed between the calls
            state = robot.state(t)
            np.testing.assert_allclose(np.degrees(q), state.q_deg, atol=1e-9)
            np.testing.assert_allclose(np.degrees(qd), state.qd_deg_s, atol=1e-9)
            seen.add(state.dwelling)
            checked += 1
            time.sleep(0.03)
        assert checked >= 30 and seen == {True, False}  # it dwelt and it moved
    finally:
        rtde.disconnect()


def test_ur_rtde_unknown_variable_is_refused_by_name(server):
    with pytest.raises(RuntimeError, match=r"not found by the controller: \[bogus_q\]"):
        rtde_receive.RTDEReceiveInterface(server.host, 500.0, ["timestamp", "bogus_q"])


def wait_until(predicate, timeout_s):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def test_ur_rtde_sees_the_controller_go_and_reconnects_when_it_returns(server):
    rtde = rtde_receive.RTDEReceiveInterface(server.host, 500.0, VARIABLES)
    try:
        server.stop()
        assert wait_until(lambda: not rtde.isConnected(), timeout_s=3.0)
        with pytest.raises(RuntimeError, match="Could not connect"):
            rtde.reconnect()  # controller still away: refused at once
        server.start()
        assert rtde.reconnect() and rtde.isConnected()
        t0 = rtde.getTimestamp()
        assert wait_until(lambda: rtde.getTimestamp() > t0, timeout_s=1.0)
        np.testing.assert_allclose(
            np.degrees(rtde.getActualQ()), make_robot().state(rtde.getTimestamp()).q_deg, atol=0.5
        )
    finally:
        rtde.disconnect()
