"""Joints from ROS (``[robot] kind = "ros"``): ``roslibpy`` against a small rosbridge-protocol
server publishing the simulated robot program's ``sensor_msgs/JointState``; a joint name the
message lacks is named, a publisher gone is retryable, and ``sim serve``'s station reads its robot
through it and hands a rehearsed program corrected targets on its target topic."""

import itertools
import time

import numpy as np
import pytest

import configs
from drivers.base import Backoff, DeviceReplyError, GarbledReply, call_with_reconnect
from drivers.ros import RosJointSource
from errors import InputError
from sim_fixtures.rosbridge_server import JOINT_NAMES, RosbridgeServer
from sim_fixtures.station_sim import SimStation
from station.config import station_config
from tests.system.moving import fails_retryably, free_address, sample, simulated_cell, two_targets


@pytest.fixture
def bridge():
    """A robot program moving between two targets, its rosbridge, the program's clock."""
    robot, t0, state = two_targets(dwell_s=0.5)
    server = RosbridgeServer(state, *free_address()).start()
    yield server, robot, t0
    server.stop()


def test_the_joints_are_the_latest_message_in_degrees(bridge):
    server, robot, t0 = bridge
    with RosJointSource(server.host, server.port, server.topic, JOINT_NAMES) as source:
        for _ in range(20):
            after = time.monotonic() - t0
            reading = source.read()
            q = np.array(reading.values["q_deg"])
            # a message at most stale_s old: where the program was within the last half second
            lo, hi = robot.state(after - 0.5).q_deg, robot.state(time.monotonic() - t0).q_deg
            assert np.all(q >= np.minimum(lo, hi) - 1e-6) and np.all(q <= np.maximum(lo, hi) + 1e-6)
            assert max(abs(v) for v in reading.values["qd_deg_s"]) <= 30.0 + 1e-6
            time.sleep(0.05)


def test_received_gives_every_message_once_in_order_stamped_at_its_arrival(bridge):
    # a sweep drains the subscription: polling the latest would skip what arrived between polls
    server, *_ = bridge
    with RosJointSource(server.host, server.port, server.topic, JOINT_NAMES) as source:
        source.received()
        start = time.monotonic()
        time.sleep(1.0)
        got = source.received() + source.received()
        end = time.monotonic()
    stamps = np.array([r.values["controller_time_s"] for r in got])
    arrivals = np.array([r.t_monotonic for r in got])
    # the bridge publishes at rate_hz (its sleeps only add): at most one message per period
    assert 0.5 * server.rate_hz <= len(got) <= (end - start) * server.rate_hz + 2
    assert np.all(np.diff(stamps) > 0) and np.all(np.diff(arrivals) >= 0)
    assert start <= arrivals[0] and arrivals[-1] <= end


def test_a_joint_the_message_lacks_is_named_and_a_bridge_gone_is_retryable(bridge):
    server, *_ = bridge
    wrong = RosJointSource(server.host, server.port, server.topic, [*JOINT_NAMES[:5], "wrist_3_joint"])
    wrong.open()
    with pytest.raises(
        DeviceReplyError, match=r"no joint 'wrist_3_joint' in the message \(it names \['joint_1'"
    ):
        wrong.read()
    wrong.close()
    source = RosJointSource(server.host, server.port, server.topic, JOINT_NAMES)
    source.open()
    server.stop()
    assert fails_retryably(source)


def test_sim_serve_publishes_its_robot_over_rosbridge_for_the_station(tmp_path):
    host, port = free_address()
    _, ds_port = free_address()
    raw = {
        "robot": {"kind": "ros", "host": host, "port": port},
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": ds_port},
        "sim": {"targets_per_line": 3, "plan_csv": str(tmp_path / "plan.csv")},
    }
    cfg = station_config(raw, "test")
    station = SimStation(cfg, hold=True)
    try:
        addresses = station.start()
        assert addresses[0] == {
            "device": "robot",
            "protocol": "rosbridge",
            "url": f"ws://{host}:{port}",
            "topic": "/joint_states",
        }
        with cfg.robot.build() as source:
            np.testing.assert_allclose(source.read().values["q_deg"], station.plan_deg[0], atol=1e-9)
    finally:
        station.stop()
    other = station_config(
        {**raw, "robot": {**raw["robot"], "joint_names": ["a", "b", "c", "d", "e", "f"]}}, "t"
    )
    with pytest.raises(InputError, match=r"\[robot\] joint_names: the simulated rosbridge publishes"):
        SimStation(other, hold=True).start()
    with pytest.raises(InputError, match="robot.topic: String should match pattern"):
        station_config({**raw, "robot": {"kind": "ros", "topic": "joint states"}}, "station.toml")


def test_a_rehearsed_ros_robot_takes_the_stations_corrected_targets_on_its_topic(tmp_path):
    """``sim serve --robot R --setup S`` over ROS: what the station publishes on ``target_topic``
    reaches the simulated program's channel (the target id and its joints)."""
    from station.commands.sim import rehearsed_cell
    from station.formats.tables import load_robot, load_setup

    robot = load_robot(configs.path("robots/abb_irb2600.toml"))
    setup = load_setup(configs.path("setups/irb2600.toml"))
    cell = rehearsed_cell(robot, setup, "setup.toml", 14, None, 5)
    host, port = free_address()
    _, ds_port = free_address()
    raw = {
        "robot": {"kind": "ros", "host": host, "port": port},
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": ds_port},
        "sim": {"plan_csv": str(tmp_path / "plan.csv")},
    }
    cfg = station_config(raw, "test")
    station = SimStation(cfg, hold=True, cell=cell)
    try:
        station.start()
        target, q = int(cell.plan_targets[3]), cell.plan_deg[3] + 0.25
        with cfg.robot.build() as source:
            source.target_channel().write(target, q)
            deadline = time.monotonic() + 2.0
            while station.channel.at(1e12) is None and time.monotonic() < deadline:
                time.sleep(0.01)
        held = station.channel.at(1e12)
        assert held is not None and held[0] == target
        np.testing.assert_allclose(held[1], q, atol=1e-9)
    finally:
        station.stop()


AT_REST = [10.0, -20.0, 30.0, 0.0, 45.0, 5.0]


@pytest.fixture(scope="module")
def still_bridge():
    """A rosbridge publishing a robot at rest at ``AT_REST`` at 20 Hz (a message stays the latest
    for 50 ms), shared by the tests of malformed messages."""
    server = RosbridgeServer(lambda: (AT_REST, [0.0] * 6), *free_address(), rate_hz=20.0).start()
    yield server
    server.stop()


@pytest.fixture
def bridge_at_rest(still_bridge):
    """The shared bridge, its ``edit`` cleared after the test."""
    yield still_bridge
    still_bridge.edit = None


def malformed(edit, times: int = 10**9):
    """An ``edit`` of the bridge: ``edit(message)`` published for the first ``times`` messages."""
    left = [times]

    def apply(message):
        left[0] -= 1
        return edit(message) if left[0] >= 0 else message

    return apply


def _set(message: dict, key: str, value) -> dict:
    return {**message, key: value}


def _velocity_2_null(message: dict) -> dict:
    return _set(message, "velocity", [*message["velocity"][:2], None, *message["velocity"][3:]])


@pytest.mark.parametrize(
    "edit, says",
    [
        (_velocity_2_null, "its velocity is neither empty nor 6 numbers"),
        (lambda m: _set(m, "position", None), "its position is not 6 numbers"),
        (lambda m: _set(m, "position", "0.1 0.2"), "its position is not 6 numbers"),
        (lambda m: _set(m, "position", m["position"][:3]), "its position is not 6 numbers"),
        (lambda m: _set(m, "position", [float("nan")] * 6), "its position is not 6 numbers"),
        (lambda m: _set(m, "position", [True] * 6), "its position is not 6 numbers"),
        (lambda m: _set(m, "position", [1e300] * 6), r"joint_1 at 5\.7\d*e\+301 deg, not an angle within"),
        (lambda m: {k: v for k, v in m.items() if k != "header"}, "its header.stamp is no time"),
        (lambda m: _set(m, "header", {"stamp": "now", "frame_id": ""}), "its header.stamp is no time"),
        (lambda m: _set(m, "name", " ".join(JOINT_NAMES)), "its name is no list of joint names"),
        (lambda m: [m], "a list, not a JointState"),
    ],
)
def test_a_malformed_message_is_refused_naming_it(bridge_at_rest, edit, says):
    """Issue 34, item 2: each was a TypeError, IndexError, KeyError or AttributeError out of read()."""
    bridge_at_rest.edit = malformed(edit)
    with RosJointSource(bridge_at_rest.host, bridge_at_rest.port, "/joint_states", JOINT_NAMES) as source:
        with pytest.raises(GarbledReply, match=says) as caught:
            source.read()
    assert str(caught.value).startswith(f"robot: rosbridge ws://{bridge_at_rest.host}:")


def test_a_malformed_message_is_retried_and_the_next_read(bridge_at_rest):
    bridge_at_rest.edit = malformed(_velocity_2_null, times=1)
    source = RosJointSource(bridge_at_rest.host, bridge_at_rest.port, "/joint_states", JOINT_NAMES)
    retried = []
    try:
        source.open()
        reading = call_with_reconnect(source, source.read, Backoff(2, 0.01), on_retry=retried.append)
    finally:
        source.close()
    np.testing.assert_allclose(reading.values["q_deg"], AT_REST)
    assert [type(e) for e in retried] == [GarbledReply]


def test_a_session_meets_a_burst_of_malformed_messages_names_them_and_measures_on(tmp_path, capsys):
    """Issue 34, item 2: one malformed message ended the session with a traceback, exit 1. Here
    15 (0.15 s) once two samples are stored."""
    with simulated_cell(tmp_path, {"kind": "ros"}) as (config, station):
        samples, burst = tmp_path / "sess" / "samples.csv", itertools.count()

        def edit(message: dict):
            stored = len(samples.read_text().splitlines()) - 1 if samples.exists() else 0
            return _velocity_2_null(message) if stored >= 2 and next(burst) < 15 else message

        station.devices["robot"].edit = edit
        code, log, rows = sample(config, capsys)
    assert code == 0 and len(rows) == 9, log
    assert "sent a message that is no JointState: its velocity is neither empty nor 6 numbers" in log
    assert "; retrying" in log and "Traceback" not in log


def test_a_publisher_stamping_every_message_0_is_measured_timed_on_arrival(tmp_path, capsys):
    """Issue 34, item 1: header.stamp 0 (a legal JointState) timed the robot's rest on a clock that
    never advances: 0 samples, "the robot never settled"."""
    with simulated_cell(tmp_path, {"kind": "ros"}) as (config, station):
        zero = {"stamp": {"secs": 0, "nsecs": 0}, "frame_id": ""}
        station.devices["robot"].edit = lambda message: {**message, "header": zero}
        code, log, rows = sample(config, capsys)
    assert code == 0 and len(rows) == 9, log
    assert log.count("its clock stands still") == 1, log


def test_without_velocities_or_advancing_stamps_the_speed_is_the_change_between_arrivals(bridge_at_rest):
    """Stamped 0 and without velocities, every message's speed was inf (over no time): never still."""
    zero = {"stamp": {"secs": 0, "nsecs": 0}, "frame_id": ""}
    bridge_at_rest.edit = lambda message: {**message, "header": zero, "velocity": []}
    with RosJointSource(bridge_at_rest.host, bridge_at_rest.port, "/joint_states", JOINT_NAMES) as source:
        assert np.isinf(source.read().values["qd_deg_s"]).all()  # one message: no speed yet
        time.sleep(0.12)  # 20 Hz: two messages later
        assert source.read().values["qd_deg_s"] == (0.0,) * 6
        assert source.read().values["qd_deg_s"] == (0.0,) * 6  # the same message again: its speed
