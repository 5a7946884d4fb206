"""Joints from ROS (``[robot] kind = "ros"``): ``roslibpy`` against a small rosbridge-protocol
server publishing the simulated robot program's ``sensor_msgs/JointState``; a joint name the
message lacks is named, a publisher gone is retryable, and ``sim serve``'s station reads its robot
through it and hands a rehearsed program corrected targets on its target topic."""

import time

import numpy as np
import pytest

import configs
from drivers.base import DeviceReplyError
from drivers.ros import RosJointSource
from errors import InputError
from sim_fixtures.rosbridge_server import JOINT_NAMES, RosbridgeServer
from sim_fixtures.station_sim import SimStation
from station.config import station_config
from tests.system.moving import fails_retryably, free_address, two_targets


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
