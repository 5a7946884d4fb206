"""A robot program that moves, served by a simulated joint source on a free loopback address: what
the OPC UA and ROS joint-source tests read; and ``station sample`` on a simulated cell with such a
robot."""

import contextlib
import random
import socket
import time
from pathlib import Path

import tomli_w

from drivers.base import RETRYABLE
from sim_fixtures.robot_program import SimRobot
from sim_fixtures.station_sim import SimStation
from station import cli
from station.commands.sim import publish_plan
from station.config import station_config
from station.formats.plan import Plan


def free_address() -> tuple[str, int]:
    """A free port on a random 127.0.0.x (other tests may serve on 127.0.0.1 at the same time)."""
    host = f"127.0.0.{random.SystemRandom().randint(2, 250)}"
    with socket.socket() as s:
        s.bind((host, 0))
        return host, s.getsockname()[1]


def two_targets(dwell_s: float):
    """A program between two targets (30 deg/s), the monotonic time it started, and its state now
    as a source serves it: ``state() -> (q_deg, qd_deg_s)``."""
    robot = SimRobot(
        [[0.0] * 6, [90.0, -45, 30, 10, 20, 60]], speed_deg_s=30.0, accel_deg_s2=60.0, dwell_s=dwell_s
    )
    t0 = time.monotonic()

    def state():
        s = robot.state(time.monotonic() - t0)
        return s.q_deg, s.qd_deg_s

    return robot, t0, state


def fails_retryably(source) -> bool:
    """Whether reading ``source`` (opened, its server stopped) raises a retryable error within 50
    reads 0.05 s apart, as a session's device loop needs to reconnect rather than give up."""
    try:
        for _ in range(50):
            source.read()
            time.sleep(0.05)
    except RETRYABLE:
        return True
    finally:
        source.close()
    return False


@contextlib.contextmanager
def simulated_cell(tmp_path: Path, robot: dict):
    """``station sim serve``'s cell (3 targets per line, 30x, no dial) with ``robot`` (a ``[robot]``
    section: its ``kind``, served on a free address) and the plan it walks published: the config's
    path and the simulated station."""
    host, port = free_address()
    _, ds_port = free_address()
    address = (
        {"url": f"opc.tcp://{host}:{port}"} if robot["kind"] == "opcua" else {"host": host, "port": port}
    )
    raw = {
        "time_scale": 30.0,
        "robot": {**address, **robot},
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": ds_port},
        "reconnect": {"attempts": 2, "initial_s": 0.05},
        "session": {"plan": "plan.csv"},
        "sim": {"speed_deg_s": 120.0, "accel_deg_s2": 480.0, "dwell_s": 2.0, "targets_per_line": 3},
    }
    raw["sim"]["plan_csv"] = str(tmp_path / "plan.csv")
    config = tmp_path / "station.toml"
    config.write_text(tomli_w.dumps(raw))
    station = SimStation(station_config(raw, str(config)))
    publish_plan(tmp_path / "plan.csv", Plan.of(station.plan_deg, station.plan_lines))
    station.start()
    try:
        yield config, station
    finally:
        station.stop()


def sample(config: Path, capsys) -> tuple[int, str, list[str]]:
    """``station sample`` on ``config`` in this process: exit code, its output, the samples' lines."""
    code = cli.main(["sample", "--config", str(config), "--out", str(config.parent / "sess")])
    out = capsys.readouterr()
    samples = config.parent / "sess" / "samples.csv"
    return code, out.out + out.err, samples.read_text().splitlines()[1:] if samples.exists() else []
