"""Joints over OPC UA (``[robot] kind = "opcua"``): ``asyncua``'s client against an ``asyncua``
server laid out as the OPC UA Robotics companion specification, fed by the simulated robot
program; what a cell's wiring gets wrong (a node id, a server gone) is named, and ``sim serve``'s
station reads its robot through it."""

import datetime as dt
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from asyncua import ua

from drivers.base import DeviceReplyError
from drivers.drawstring import RegisterMap
from drivers.opcua import OpcUaJointSource
from errors import InputError
from sim_fixtures.modbus_device import ModbusDevice
from sim_fixtures.opcua_server import OpcUaRobotServer, position_node, speed_node
from sim_fixtures.station_sim import SimStation
from station import cli
from station.config import station_config
from tests.system.moving import (
    RETRYABLE,
    fails_retryably,
    free_address,
    sample,
    simulated_cell,
    two_targets,
)

ROOT = Path(__file__).resolve().parents[2]
POSITIONS = [position_node(i) for i in range(1, 7)]
SPEEDS = [speed_node(i) for i in range(1, 7)]


@pytest.fixture
def moving():
    """A robot program between two targets (30 deg/s), its OPC UA server, the program's clock."""
    robot, t0, state = two_targets(dwell_s=1.0)
    server = OpcUaRobotServer(state, *free_address()).start()
    yield server, robot, t0
    server.stop()


def test_the_joints_are_the_robot_programs_at_the_instant_read(moving):
    server, robot, t0 = moving
    with OpcUaJointSource(server.url, POSITIONS, SPEEDS) as source:
        for _ in range(40):
            before = time.monotonic() - t0
            reading = source.read()
            after = time.monotonic() - t0
            q = np.array(reading.values["q_deg"])
            lo, hi = robot.state(before).q_deg, robot.state(after).q_deg
            # between where the program was when the read left and when it came back
            assert np.all(q >= np.minimum(lo, hi) - 1e-9) and np.all(q <= np.maximum(lo, hi) + 1e-9)
            assert reading.values["robot_mode"] == 7
            time.sleep(0.05)
        assert max(abs(v) for v in reading.values["qd_deg_s"]) <= 30.0 + 1e-9


def test_without_speed_nodes_the_speed_is_the_change_between_reads(moving):
    server, robot, t0 = moving
    with OpcUaJointSource(server.url, POSITIONS) as source:
        assert np.isinf(source.read().values["qd_deg_s"]).all()  # one read: no speed yet, not settled
        time.sleep(max(0.0, 6.6 - (time.monotonic() - t0)))  # cruising at 30 deg/s (joint 1 leads)
        source.read()
        time.sleep(0.2)
        t = time.monotonic() - t0
        qd = source.read().values["qd_deg_s"][0]
        assert qd == pytest.approx(robot.state(t).qd_deg_s[0], rel=0.1)


def test_a_node_the_server_lacks_is_named_and_a_server_gone_is_retryable(moving):
    server, *_ = moving
    wrong = [*POSITIONS[:5], "ns=2;s=DeviceSet/Robot/Axes/Axis6/ParameterSet/ActualPositon"]
    source = OpcUaJointSource(server.url, wrong)
    with pytest.raises(
        DeviceReplyError, match=r"node ns=2;s=.*Axis6/ParameterSet/ActualPositon: BadNodeIdUnknown"
    ):
        source.open()
    source.close()
    source = OpcUaJointSource(server.url, POSITIONS, timeout_s=0.5)
    source.open()
    server.stop()
    assert fails_retryably(source)


@pytest.fixture
def sampled():
    """The two-target program (at rest for 0.8 s at each) on a server sampling it every 5 ms for a
    subscribed client; the program and its start [s, monotonic], which a test may set anew."""
    robot, _, _ = two_targets(dwell_s=0.8)
    start = [time.monotonic()]

    def state():
        now = robot.state(time.monotonic() - start[0])
        return now.q_deg, now.qd_deg_s

    server = OpcUaRobotServer(state, *free_address(), sample_s=0.005).start()
    yield server, robot, start
    server.stop()


def received_for(source, seconds: float) -> list:
    """Every reading ``source``'s subscription gave for ``seconds``, drained every 20 ms."""
    readings, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        readings += source.received()
        time.sleep(0.02)
    return readings


def off(stamps: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """How far [s] each ``wanted`` time is from the nearest of ``stamps`` (ascending)."""
    i = np.searchsorted(stamps, wanted)
    return np.minimum(
        np.abs(stamps[np.clip(i, 0, len(stamps) - 1)] - wanted),
        np.abs(stamps[np.clip(i - 1, 0, None)] - wanted),
    )


def test_a_subscription_gives_every_sample_whole_on_the_servers_timestamps(sampled):
    server, robot, start = sampled
    with OpcUaJointSource(server.url, POSITIONS, SPEEDS, subscription_ms=20.0) as source:
        start[0] = t0 = time.monotonic()  # the program starts now: at rest for its first 0.8 s
        readings = received_for(source, 2.0)
    stamps = np.array([r.values["controller_time_s"] for r in readings])
    assert np.all(np.diff(stamps) > 0)  # one reading a sample, in order
    # every sample the server took in that time, not one a publish, at rest too (its timestamp
    # changes, its value does not)
    sampled = np.array(server.sampled)
    taken = sampled[(sampled > stamps[0]) & (sampled <= stamps[-1])]
    assert len(taken) > 50 and off(stamps, taken).max() < 1e-6
    at_rest = [r for r in readings if r.values["q_deg"] == (0.0,) * 6]
    assert len(at_rest) > 20
    # each reading is one sample of the program: its six joints at one instant of the program
    offset = np.median([r.t_wall - r.t_monotonic for r in readings])
    for r in readings:
        t = r.values["controller_time_s"] - offset - t0
        if t < 0.01:
            continue  # sampled before the program started again
        ahead = np.array([robot.state(t + d).q_deg for d in (-0.05, 0.05)])
        q = np.array(r.values["q_deg"])
        assert np.all(q >= ahead.min(0) - 1e-9) and np.all(q <= ahead.max(0) + 1e-9)
        assert r.t_monotonic - t0 >= t - 0.01  # it arrived after it was taken


def test_a_server_that_stamps_its_axes_apart_gives_readings_with_the_rest_held(sampled):
    server, _, _ = sampled

    def apart(joint, index, answer):  # each axis sampled 0.5 ms after the one before (within a cycle)
        stamp = answer.SourceTimestamp + dt.timedelta(microseconds=500 * joint)
        return ua.DataValue(answer.Value, SourceTimestamp=stamp, ServerTimestamp=stamp)

    server.edit = apart
    with OpcUaJointSource(server.url, POSITIONS, subscription_ms=20.0) as source:
        readings = received_for(source, 1.0)
    stamps = np.array([r.values["controller_time_s"] for r in readings])
    # a reading for each axis's own timestamp of every sample, the other axes held
    sampled = np.array(server.sampled)
    sampled = sampled[(sampled > stamps[0]) & (sampled < stamps[-1] - 0.01)]
    assert np.all(np.diff(stamps) > 0) and len(sampled) > 50
    assert off(stamps, sampled[:, None] + 0.5e-3 * np.arange(6)).max() < 1e-6


def test_a_subscribed_server_gone_is_found_within_its_timeout(sampled):
    server, _, _ = sampled
    source = OpcUaJointSource(server.url, POSITIONS, subscription_ms=20.0, timeout_s=0.5)
    source.open()
    received_for(source, 0.3)
    server.stop()
    start = time.monotonic()
    with pytest.raises(RETRYABLE):
        received_for(source, 5.0)
    assert time.monotonic() - start < 0.5 + 1.5 + 0.5  # the check's period, a read's wait, slack
    source.close()


def test_sim_serve_publishes_its_robot_over_opcua_for_the_station(tmp_path):
    host, port = free_address()
    _, ds_port = free_address()
    raw = {
        "robot": {"kind": "opcua", "url": f"opc.tcp://{host}:{port}"},  # the node ids: their defaults
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": ds_port},
        "sim": {"targets_per_line": 3, "plan_csv": str(tmp_path / "plan.csv")},
    }
    cfg = station_config(raw, "test")
    assert cfg.robot.endpoint() == f"opcua opc.tcp://{host}:{port}"
    station = SimStation(cfg, hold=True)
    try:
        addresses = station.start()
        assert addresses[0] == {
            "device": "robot",
            "protocol": "opcua",
            "url": cfg.robot.url,
            "time_scale": 1.0,
        }
        with cfg.robot.build() as source:
            np.testing.assert_allclose(source.read().values["q_deg"], station.plan_deg[0])
    finally:
        station.stop()
    other = station_config({**raw, "robot": {**raw["robot"], "position_node": "ns=3;i={axis}"}}, "test")
    with pytest.raises(InputError, match=r"\[robot\] position_node, speed_node: the simulated OPC UA server"):
        SimStation(other, hold=True).start()


@pytest.mark.parametrize(
    "robot, message",
    [
        ({"url": "http://x:4840"}, "robot.url: String should match pattern"),
        (
            {"position_node": "ns=2;s=Axis1.ActualPosition"},
            "robot.position_node: 'ns=2;s=Axis1.ActualPosition': write {axis}",
        ),
        ({"unit": "grad"}, "robot.unit: Input should be 'deg' or 'rad'"),
        ({"position_node": "garbage{axis}"}, r"robot.position_node: 'garbage1': not an OPC UA node id"),
        ({"speed_node": "ns=2;i=x{axis}"}, r"robot.speed_node: 'ns=2;i=x1': not an OPC UA node id"),
        ({"target_node": "ns=70000;i={axis}"}, r"robot.target_node: 'ns=70000;i=1': namespace index"),
        ({"target_index_node": "i=4294967296"}, r"robot.target_index_node: 'i=4294967296': numeric id"),
        ({"position_node": "i=429496729{axis}"}, r"robot.position_node: 'i=4294967296': numeric id"),
    ],
)
def test_a_wrong_opcua_section_is_one_line_naming_the_key(robot, message):
    raw = {
        "robot": {"kind": "opcua", **robot},
        "drawstring": {"kind": "modbus_tcp"},
    }
    with pytest.raises(InputError, match=message):
        station_config(raw, "station.toml")


def test_station_read_refuses_a_node_id_that_is_none_in_one_line_exit_2(moving, tmp_path, capsys):
    """Issue 34, item 4: ``garbage{axis}`` was asyncua's parsing traceback once connected."""
    config = tmp_path / "station.toml"
    config.write_text(
        f'[robot]\nkind = "opcua"\nurl = "{moving[0].url}"\nposition_node = "garbage{{axis}}"\n\n'
        '[drawstring]\nkind = "modbus_tcp"\n'
    )
    assert cli.main(["read", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "robot.position_node: 'garbage1': not an OPC UA node id" in err, err


def station_read(
    tmp_path, url: str, timeout_s: float = 1.0, drawstring: int = 1
) -> subprocess.CompletedProcess:
    """``station read`` in a process of its own (its stderr as the user sees it, and its end) on an
    OPC UA robot at ``url`` (2 attempts) and a Modbus TCP drawstring on port ``drawstring`` (1:
    none, so a robot read exits 1 too, naming the drawstring)."""
    config = tmp_path / "station.toml"
    config.write_text(
        f'[robot]\nkind = "opcua"\nurl = "{url}"\ntimeout_s = {timeout_s}\n\n'
        f'[drawstring]\nkind = "modbus_tcp"\nport = {drawstring}\n\n[reconnect]\nattempts = 2\n'
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "station.cli", "read", "--config", str(config)],
        capture_output=True, text=True, timeout=30, env=env, cwd=tmp_path,
    )  # fmt: skip


def test_a_server_that_does_not_answer_in_time_is_one_line_saying_so(moving, tmp_path):
    """Issue 34, item 5: a server stalled 3 s at its first value read (its event loop blocked) was
    "cannot connect to ...: " with no reason and asyncua's tracebacks on stderr."""
    server, *_ = moving
    stalled = []

    def stall_once(joint, index, value):
        if not stalled:
            stalled.append(time.sleep(3.0))
        return value

    server.edit = stall_once
    proc = station_read(tmp_path, server.url, timeout_s=0.3)
    assert proc.returncode == 1 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1, proc.stderr
    assert f"OPC UA {server.url} did not answer within 0.3 s" in proc.stderr, proc.stderr


def answering(value: ua.Variant, joint: int = 2, index: int = 0, times: int = 10**9):
    """An ``edit`` of the simulated server: joint ``joint``'s position (``index`` 1: speed) holds
    ``value`` for the first ``times`` reads, then the program's."""
    left = [times]

    def edit(j, i, answer):
        if (j, i) != (joint, index) or left[0] <= 0:
            return answer
        left[0] -= 1
        return ua.DataValue(value, SourceTimestamp=answer.SourceTimestamp)

    return edit


AT_REST = [10.0, -20.0, 30.0, 0.0, 45.0, 5.0]


@pytest.fixture(scope="module")
def cell():
    """A robot at rest at ``AT_REST`` on its OPC UA server and a Modbus TCP drawstring (the
    config's default registers) reading 1234.5 mm, shared by the tests of hostile values."""
    server = OpcUaRobotServer(lambda: (AT_REST, [0.0] * 6), *free_address()).start()
    with ModbusDevice(RegisterMap(), lambda: 1234.5, tcp=("127.0.0.1", 0)) as drawstring:
        yield server, drawstring.address["port"]
    server.stop()


@pytest.fixture
def at_rest(cell):
    """The shared cell, its server's ``edit`` cleared after the test."""
    yield cell
    cell[0].edit = None


def read_with(tmp_path, url: str, drawstring: int, capsys) -> tuple[int, str, str]:
    """``station read`` (2 attempts) in this process: exit code, stdout, stderr."""
    config = tmp_path / "station.toml"
    config.write_text(
        f'[robot]\nkind = "opcua"\nurl = "{url}"\n\n'
        f'[drawstring]\nkind = "modbus_tcp"\nport = {drawstring}\n\n'
        "[reconnect]\nattempts = 2\ninitial_s = 0.01\n"
    )
    code = cli.main(["read", "--config", str(config)])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize(
    "value, index, says",
    [
        (
            ua.Variant(float("nan"), ua.VariantType.Double),
            0,
            "Axis3/ParameterSet/ActualPosition holds nan deg",
        ),
        (ua.Variant(float("inf"), ua.VariantType.Double), 0, "ActualPosition holds inf deg, not an angle"),
        (ua.Variant(1e300, ua.VariantType.Double), 0, r"holds 1e\+300 deg, not an angle within"),
        (ua.Variant(10**18, ua.VariantType.Int64), 0, r"holds 1e\+18 deg, not an angle within"),
        (ua.Variant(True, ua.VariantType.Boolean), 0, "ActualPosition holds True, a Boolean, not a number"),
        (ua.Variant("12.5", ua.VariantType.String), 0, "ActualPosition holds '12.5', a String, not a number"),
        (
            ua.Variant(float("nan"), ua.VariantType.Double),
            1,
            "Axis3/ParameterSet/ActualSpeed holds nan deg/s",
        ),
        (ua.Variant([1.0, 2.0], ua.VariantType.Double), 0, r"holds \[1.0, 2.0\], an array, not a number"),
    ],
)
def test_a_value_that_is_no_angle_is_refused_naming_the_node(at_rest, tmp_path, capsys, value, index, says):
    """Issue 34, item 3: NaN, inf, 1e300, a Boolean (1.0 deg), the String "12.5" and an Int64 1e18
    were read as angles, `station read` exit 0."""
    server, drawstring = at_rest
    server.edit = answering(value, index=index)
    code, out, err = read_with(tmp_path, server.url, drawstring, capsys)
    assert code == 1 and out == "" and err.count("\n") == 1, err
    assert re.search(says, err), err


def test_a_value_that_is_no_angle_once_is_retried_and_read(at_rest, tmp_path):
    """Retried with a reconnect, in a process of its own: the retry's client was opened over the
    one before, whose thread then kept the process alive after its output."""
    server, drawstring = at_rest
    server.edit = answering(ua.Variant(float("nan"), ua.VariantType.Double), times=1)
    proc = station_read(tmp_path, server.url, drawstring=drawstring)
    assert proc.returncode == 0 and proc.stderr == ""
    assert json.loads(proc.stdout)["q_deg"] == AT_REST


def stamped_on_change():
    """An ``edit`` of the simulated server: each value's SourceTimestamp is when it last changed
    (a server sampling on change, as OPC UA Part 4 allows), not when it was read."""
    changed = {}

    def edit(joint, index, answer):
        value, stamp = changed.get((joint, index), (None, None))
        if value != answer.Value.Value:
            changed[joint, index] = value, stamp = answer.Value.Value, answer.SourceTimestamp
        return ua.DataValue(answer.Value, SourceTimestamp=stamp, ServerTimestamp=answer.ServerTimestamp)

    return edit


def test_a_server_stamping_values_on_change_is_measured_timed_on_arrival(tmp_path, capsys):
    """Issue 34, item 1: the robot at rest holds its SourceTimestamp, so its rest, timed on that
    clock, never lasted: 0 samples, "the robot never settled"."""
    with simulated_cell(tmp_path, {"kind": "opcua"}) as (config, station):
        station.devices["robot"].edit = stamped_on_change()
        code, log, rows = sample(config, capsys)
    assert code == 0 and len(rows) == 9, log
    assert log.count("its clock stands still") == 1, log
