"""A controller's joint convention (a robot file's ``[controller]``: ``q_model = joint_sign * reading
+ joint_offset_deg``), KUKA-like: A1, A4 and A6 turning against the model's axes, A2 and A3 zeroed
elsewhere. ``station sim serve`` presents such a controller (RTDE, OPC UA, ROS); the station reads
the model's joints through it, writes the controller's to its target channel, stores its samples at
the right targets, and names a robot file whose signs are wrong, with the fix."""

import csv
import re

import numpy as np
import pytest
import tomli_w

import configs
from calib.conventions import controller_joints
from sim_fixtures.station_sim import SimStation
from station.commands.sim import publish_plan, rehearsed_cell
from station.config import station_config
from station.formats.plan import Plan
from station.formats.tables import Controller, load_robot, load_setup
from tests.system.moving import free_address, sample
from tests.system.test_sim_serve import own_cell, run_cli, serving

SIGN = [-1, 1, 1, -1, 1, -1]
OFFSET = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
KUKA = Controller(joint_sign=SIGN, joint_offset_deg=OFFSET)
KINDS = ("rtde", "opcua", "ros")


def robot_section(kind: str) -> dict:
    """A ``[robot]`` section of ``kind`` on a free loopback address (RTDE's port is fixed)."""
    host, port = free_address()
    return {
        "rtde": {"kind": "rtde", "host": host},
        "opcua": {"kind": "opcua", "url": f"opc.tcp://{host}:{port}"},
        "ros": {"kind": "ros", "host": host, "port": port},
    }[kind]


def config_of(tmp_path, kind: str, **sim) -> dict:
    """``sim serve``'s JR680 cell (3 targets per line, 30x, no dial), the robot over ``kind``."""
    _, ds_port = free_address()
    return {
        "time_scale": 30.0,
        "robot": robot_section(kind),
        "drawstring": {"kind": "modbus_tcp", "host": "127.0.0.1", "port": ds_port},
        "reconnect": {"attempts": 2, "initial_s": 0.05},
        "session": {"plan": "plan.csv", "robot_model": "robot.toml"},
        "sim": {
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 2.0,
            "targets_per_line": 3,
            "plan_csv": str(tmp_path / "plan.csv"),
            **sim,
        },
    }


def robot_file(tmp_path, text: str = "robots/hsr_jr680.toml", controller: Controller | None = KUKA):
    """The shipped robot file ``text`` at ``tmp_path/robot.toml``, with ``controller`` appended."""
    body = configs.path(text).read_text()
    if controller is not None:
        body += "\n" + tomli_w.dumps({"controller": controller.model_dump()})
    path = tmp_path / "robot.toml"
    path.write_text(body)
    return path


@pytest.mark.parametrize("kind", KINDS)
def test_the_simulated_controller_publishes_its_joints_and_the_station_reads_the_models(tmp_path, kind):
    cfg = station_config(config_of(tmp_path, kind), "test")
    station = SimStation(cfg, hold=True, convention=(SIGN, OFFSET))
    try:
        station.start()
        target = station.plan_deg[0]  # --hold: the robot stays at its first target
        with cfg.robot.build() as wire:  # the controller's own readings
            np.testing.assert_allclose(wire.read().values["q_deg"], controller_joints(target, SIGN, OFFSET))
        robot = cfg.drivers(KUKA)["robot"]
        with robot:
            reading = robot.read()
            np.testing.assert_allclose(reading.values["q_deg"], target, atol=1e-9)
            assert reading.values["robot_mode"] == 7
        with cfg.drivers(Controller())["robot"] as plain:  # a robot file without [controller]
            assert np.max(np.abs(np.asarray(plain.read().values["q_deg"]) - target)) > 90
    finally:
        station.stop()


@pytest.mark.parametrize("kind", KINDS)
def test_targets_written_in_the_models_joints_reach_the_simulated_program_as_the_models(tmp_path, kind):
    """Rehearsed IRB 2600 cell (its program takes corrected targets): a target written through the
    station's channel is the controller's joints on the wire, the model's in the program."""
    raw = config_of(tmp_path, kind)
    cfg = station_config(raw, "test")
    setup = load_setup(configs.path("setups/irb2600.toml"))
    robot = load_robot(robot_file(tmp_path, "robots/abb_irb2600.toml"))
    cell = rehearsed_cell(robot, setup, "irb2600.toml", 14, None, 3)
    station = SimStation(cfg, hold=True, cell=cell, convention=(SIGN, OFFSET))
    q_model = cell.plan_deg[4] + [1.0, -0.5, 0.25, 2.0, -1.5, 3.0]
    try:
        station.start()
        with cfg.drivers(robot.controller)["robot"] as driver:
            driver.target_channel().write(4, q_model)
            held = _held(station, 4)
            np.testing.assert_allclose(held, q_model, atol=1e-5)  # joint 6 over RTDE: 1 urad
        with cfg.robot.build() as wire:  # the controller's joints written as they are: the same
            wire.target_channel().write(5, controller_joints(q_model, SIGN, OFFSET))
            np.testing.assert_allclose(_held(station, 5), q_model, atol=1e-5)
    finally:
        station.stop()


def _held(station, target: int, tries: int = 100) -> np.ndarray:
    """What the simulated program's channel holds for ``target`` (a write crosses a process or a
    thread: waited for, up to ``tries`` x 0.05 s)."""
    import time

    for _ in range(tries):
        held = station.channel.at(float("inf"))
        if held is not None and held[0] == target:
            return held[1]
        time.sleep(0.05)
    pytest.fail(f"target {target} never reached the simulated program")


@pytest.mark.parametrize("kind", ("rtde", "opcua"))
def test_a_session_against_a_kuka_convention_stores_model_joints_at_the_right_targets(tmp_path, capsys, kind):
    raw = config_of(tmp_path, kind)
    config = tmp_path / "station.toml"
    config.write_text(tomli_w.dumps(raw))
    robot_file(tmp_path)
    station = SimStation(station_config(raw, str(config)), convention=(SIGN, OFFSET))
    publish_plan(tmp_path / "plan.csv", Plan.of(station.plan_deg, station.plan_lines))
    station.start()
    try:
        code, log, _ = sample(config, capsys)
    finally:
        station.stop()
    assert code == 0, log
    rows = list(csv.DictReader(open(tmp_path / "sess" / "samples.csv")))
    assert sorted(int(r["target"]) for r in rows) == list(range(9))
    still = station_config(raw, "test").session.still_deg  # a capture's joints span at most this
    for r in rows:
        q = [float(r[f"q{i}_deg"]) for i in range(1, 7)]
        np.testing.assert_allclose(q, station.plan_deg[int(r["target"])], atol=still)


CELL = own_cell(
    '[robot]\nkind = "rtde"\nhost = "{host}"\n',
    sim="targets_per_line = 4\njoint_sign = [-1, 1, 1, -1, 1, -1]\n",
    head="time_scale = 40.0\n",
)


def test_a_robot_file_without_kukas_signs_is_named_with_the_fix(tmp_path, monkeypatch):
    """A KUKA rehearsed (``[sim] joint_sign``) with a robot file that lacks its ``[controller]``:
    the robot settles away from every target; the session says which signs are flipped and what to
    set, in the log and in its ending (exit 1: no capture)."""
    monkeypatch.chdir(tmp_path)
    robot_file(tmp_path, "robots/abb_irb2600.toml", controller=None)
    (tmp_path / "setup.toml").write_text(configs.path("setups/irb2600.toml").read_text())
    flags = ("--robot", "robot.toml", "--setup", "setup.toml")
    with serving(tmp_path, *flags, config_text=CELL) as (_, config, _):
        sampled = run_cli("sample", "--config", str(config), "--out", "session", timeout=120)
    assert sampled.returncode == 1, sampled.stderr
    advice = (
        r"the robot settled (\d+) times away from every target; with joint 1's, 4's and 6's signs "
        r"flipped, (\d+) of them lie at targets [\d, ]+: set \[controller\] joint_sign = "
        r"\[-1, 1, 1, -1, 1, -1\] in \S*robot.toml"
    )
    said = re.findall(advice, sampled.stdout)
    assert len(said) == 2, sampled.stdout[-3000:]  # once in the log, once in the ending
    ending = next(line for line in sampled.stdout.splitlines() if line.startswith("timed out:"))
    assert ending.startswith("timed out: no capture") and re.search(advice, ending), ending
    assert "Traceback" not in sampled.stdout + sampled.stderr
