"""End to end: ``station sim serve`` in a subprocess on non-contract addresses, then
``station read`` and ``station sample`` against it through the real drivers; signals, unreachable
devices, bad config."""

import contextlib
import csv
import importlib.util
import json
import queue
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from sim_fixtures.station_sim import make_cell
from station.formats.plan import Plan, load_plan

# The real entry point, limited to the commands present on this branch (siblings such as
# ``demo`` arrive with other branches).
CLI = [
    sys.executable,
    "-c",
    (
        "import importlib.util, sys, station.cli as c; "
        "c.COMMANDS = tuple(n for n in c.COMMANDS "
        "if importlib.util.find_spec('station.commands.' + n)); sys.exit(c.main())"
    ),
]
assert importlib.util.find_spec("station.commands.sim")

CONFIG = """
time_scale = 20.0
[robot]
kind = "rtde"
host = "{host}"
[drawstring]
kind = "modbus_tcp"
host = "127.0.0.1"
port = {port}
timeout_s = 0.3
[dial]
port = "{dial}"
dialect = "mitutoyo"
[reconnect]
attempts = 2
initial_s = 0.05
"""


def own_cell(robot: str, sim: str = "", head: str = "") -> str:
    """A rehearsed cell's station config (``sim serve --robot robot.toml --setup setup.toml``,
    seed 14, the plan at ``sim/plan.csv``) with its ``[robot]`` section ``robot``, ``sim`` keys added
    to ``[sim]`` and ``head`` (top-level keys) first; ``{host}``, ``{port}``, ``{dial}`` as
    :func:`write_config` fills them."""
    return (
        f'{head}[session]\nrobot_model = "robot.toml"\nsetup = "setup.toml"\nplan = "sim/plan.csv"\n{robot}'
        '[drawstring]\nkind = "modbus_tcp"\nport = {port}\n[dial]\nport = "{dial}"\n'
        f'[sim]\nseed = 14\nplan_csv = "sim/plan.csv"\n{sim}'
    )


def write_config(tmp_path, text: str = CONFIG, extra: str = "") -> Path:
    """``tmp_path/station.toml``: ``text`` on a random loopback RTDE address and a free Modbus
    port, then ``extra``."""
    host = f"127.0.0.{random.randint(2, 250)}"
    config = tmp_path / "station.toml"
    config.write_text(text.format(host=host, port=free_port(), dial=tmp_path / "dial") + extra)
    return config


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def lines_of(proc) -> queue.Queue:
    """Stdout lines of ``proc``, read by a daemon thread (``None`` at EOF)."""
    out: queue.Queue = queue.Queue()

    def pump():
        for line in proc.stdout:
            out.put(line)
        out.put(None)

    threading.Thread(target=pump, daemon=True).start()
    return out


def run_cli(*args, timeout=60):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout)


def stop(proc) -> int:
    """End ``sim serve`` as an operator would (SIGTERM), killing it only if that fails."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            return proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait(timeout=15)


@pytest.fixture
def served(tmp_path):
    """``sim serve --hold`` on a random loopback RTDE address and a free Modbus port."""
    with serving(tmp_path, "--hold") as started:
        yield started


@contextlib.contextmanager
def serving(tmp_path, *flags, extra_config="", config_text=CONFIG):
    """``sim serve`` with ``flags`` on a random loopback RTDE address and a free Modbus port, its
    config ``config_text`` followed by ``extra_config``: (process, config path, printed addresses)."""
    for _ in range(3):
        config = write_config(tmp_path, config_text, extra_config)
        with open(tmp_path / "serve.err", "w") as err:
            proc = subprocess.Popen(
                [*CLI, "sim", "serve", "--config", str(config), *flags],
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
            )
        out = lines_of(proc)
        try:
            addresses = [json.loads(out.get(timeout=30)) for _ in range(3)]
        except (TypeError, queue.Empty):  # EOF (address taken) or stuck: stop it, try again
            stop(proc)
            continue
        try:
            yield proc, config, addresses
        finally:
            stop(proc)
        return
    pytest.fail(f"sim serve did not start: {(tmp_path / 'serve.err').read_text()}")


def test_sim_serve_prints_addresses_and_read_gets_every_device(served):
    proc, config, addresses = served
    text = config.read_text()
    robot, drawstring, dial = addresses
    assert robot["device"] == "robot" and robot["protocol"] == "rtde" and robot["port"] == 30004
    assert f'host = "{robot["host"]}"' in text
    assert drawstring["protocol"] == "modbus-tcp" and f"port = {drawstring['port']}" in text
    assert dial["protocol"] == "serial-ascii" and dial["pty"].startswith("/dev/pts/")
    assert dial["port"] == str(config.parent / "dial") and dial["dialect"] == "mitutoyo"

    before = time.time()
    result = run_cli("read", "--config", str(config))
    assert result.returncode == 0, result.stderr
    reading = json.loads(result.stdout)
    cell = make_cell(0)
    target = cell.plan_deg[0]  # --hold: the robot stays at its first target
    assert np.allclose(reading["q_deg"], target, atol=0.01)
    assert reading["length_mm"] == pytest.approx(cell.true_length_mm(target)[0], abs=0.1)
    true_dial = cell.true_dial_mm(target[None], cell.plan_lines[:1])[0]  # the placement offset
    assert reading["dial_mm"] == pytest.approx(true_dial, abs=0.01)
    assert set(reading["devices"]) == {"robot", "drawstring", "dial"}
    for device in reading["devices"].values():
        assert before - 1 < device["t_wall"] < time.time() + 1
    assert reading["devices"]["drawstring"]["units"] == {"length_mm": "mm"}


# A small fast cell: 3 targets on each of 3 lines, a quick robot, 20x simulated time.
FAST_SESSION = """
[session]
plan = "{plan}"
[sim]
speed_deg_s = 120.0
accel_deg_s2 = 480.0
dwell_s = 2.0
targets_per_line = 3
plan_csv = "{plan}"
"""


def test_sample_without_plan_measures_the_plan_sim_serve_published(tmp_path):
    plan_path = tmp_path / "published" / "plan.csv"
    with serving(tmp_path, extra_config=FAST_SESSION.format(plan=plan_path)) as (_, config, _):
        result = run_cli("sample", "--config", str(config), "--out", str(tmp_path / "sess"))
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.splitlines()[-1].startswith(f"saved: 9/9 samples in {tmp_path / 'sess'}")
    cell, plan = make_cell(0, 3), load_plan(plan_path)
    np.testing.assert_allclose(plan.q_deg, cell.plan_deg, atol=1e-6)  # the cell's own plan
    with (tmp_path / "sess" / "samples.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    targets = np.array([int(r["target"]) for r in rows])
    assert sorted(targets) == list(range(9))
    q = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in rows])
    # the simulated robot dwells exactly at each target; both files keep 6 decimals
    assert np.abs(q - plan.q_deg[targets]).max() < 1e-5
    assert f'plan_source = "{plan_path}"' in (tmp_path / "sess" / "session.toml").read_text()


REAL_TIME = CONFIG.replace("time_scale = 20.0", "time_scale = 1.0")  # the shipped config's time scale


def test_sample_runs_at_the_time_scale_sim_serve_announces_and_refuses_another(tmp_path):
    # the config says real time; sim serve --time-scale 20 runs the robot 20x faster: a sample at
    # real time would wait 0.5 s to settle at targets the robot leaves after 0.15 s, and time out
    plan_path = tmp_path / "published" / "plan.csv"
    fast = FAST_SESSION.format(plan=plan_path)
    with serving(tmp_path, "--time-scale", "20", extra_config=fast, config_text=REAL_TIME) as started:
        _, config, addresses = started
        announced = plan_path.parent / "simulator.toml"
        assert addresses[0]["time_scale"] == 20.0 and announced.exists()
        refused = run_cli(
            "sample", "--config", str(config), "--out", str(tmp_path / "a" / "s"), "--time-scale", "1"
        )
        t0 = time.monotonic()
        result = run_cli("sample", "--config", str(config), "--out", str(tmp_path / "sess"))
        took_s = time.monotonic() - t0
    assert refused.returncode == 2 and refused.stdout == ""
    assert refused.stderr.startswith("station: error: --time-scale 1: the simulated robot at rtde ")
    assert "runs at time scale 20 (`station sim serve`" in refused.stderr and refused.stderr.count("\n") == 1
    assert not (tmp_path / "a").exists()
    assert result.returncode == 0, result.stdout + result.stderr
    assert "time scale 20: the simulated robot's (`station sim serve`" in result.stdout
    assert result.stdout.splitlines()[-1].startswith(f"saved: 9/9 samples in {tmp_path / 'sess'}")
    assert "time_scale = 20.0" in (tmp_path / "sess" / "session.toml").read_text()
    assert took_s < 60  # 9 targets at 20x; at real time alone the robot's walk takes over 40 s
    assert not announced.exists()  # withdrawn when sim serve stopped


def test_a_stale_announcement_is_ignored_and_time_scale_sets_the_pace(tmp_path):
    plan_path = tmp_path / "published" / "plan.csv"
    fast = FAST_SESSION.format(plan=plan_path)
    with serving(tmp_path, "--time-scale", "20", extra_config=fast, config_text=REAL_TIME) as (
        proc,
        config,
        _,
    ):
        announced = plan_path.parent / "simulator.toml"
        # a simulator killed without its clean-up leaves its announcement: a process that is gone
        announced.write_text(announced.read_text().replace(f"pid = {proc.pid}", "pid = 999999999"))
        result = run_cli(
            "sample", "--config", str(config), "--out", str(tmp_path / "sess"), "--time-scale", "20"
        )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "time scale 20: the simulated robot's" not in result.stdout
    assert "time_scale = 20.0" in (tmp_path / "sess" / "session.toml").read_text()


def test_an_unreachable_device_leaves_no_session_folder_and_the_retry_works(tmp_path):
    plan_path = tmp_path / "published" / "plan.csv"
    fast = FAST_SESSION.format(plan=plan_path)
    plan_path.parent.mkdir()
    plan_path.write_text(Plan.of(make_cell(0, 3).plan_deg, make_cell(0, 3).plan_lines).csv_text())
    config = write_config(tmp_path, extra=fast)  # nothing serves these addresses
    out = tmp_path / "runs" / "today" / "run1"
    failed = run_cli("sample", "--config", str(config), "--out", str(out))
    assert failed.returncode == 1, failed.stdout + failed.stderr
    assert failed.stderr.startswith("station: device error: robot: unreachable after 2 attempts")
    assert failed.stderr.endswith("(is `station sim serve` running, or the station's wiring up?)\n")
    assert not (tmp_path / "runs").exists()  # no session folder, no parents
    with serving(tmp_path, extra_config=fast):
        retry = run_cli("sample", "--config", str(config), "--out", str(out))
    assert retry.returncode == 0, retry.stdout + retry.stderr
    assert retry.stdout.splitlines()[-1].startswith(f"saved: 9/9 samples in {out}")


def test_read_with_no_simulator_exits_1_with_the_hint(tmp_path):
    result = run_cli("read", "--config", str(write_config(tmp_path)))
    assert result.returncode == 1 and result.stdout == ""
    assert result.stderr.startswith("station: device error: robot: unreachable after 2 attempts")
    assert result.stderr.endswith("(is `station sim serve` running, or the station's wiring up?)\n")
    assert result.stderr.count("\n") == 1


def test_sim_serve_stops_on_sigterm_and_removes_links(served):
    proc, config, _ = served
    assert (config.parent / "dial").is_symlink()
    assert stop(proc) == 0
    assert not (config.parent / "dial").exists()


def test_read_exits_1_naming_the_unreachable_device(served):
    _, config, addresses = served
    dead = config.parent / "dead.toml"
    dead.write_text(config.read_text().replace(f"port = {addresses[1]['port']}", f"port = {free_port()}"))
    result = run_cli("read", "--config", str(dead))
    assert result.returncode == 1
    assert result.stderr.startswith("station: device error: drawstring: unreachable after 2 attempts")
    assert result.stdout == ""


@pytest.mark.parametrize("command", [["read"], ["sim", "serve"]])
def test_bad_config_exits_2_with_one_line(tmp_path, command):
    bad = tmp_path / "station.toml"
    bad.write_text(CONFIG.format(host="127.0.0.1", port=0, dial=tmp_path / "dial"))
    result = run_cli(*command, "--config", str(bad), timeout=30)
    assert result.returncode == 2
    assert result.stderr == (f"station: error: {bad}: drawstring.port: Input should be greater than 0\n")


@pytest.mark.parametrize(
    "drawstring",
    [
        'kind = "modbus_rtu"\nport = "{dir}/ds-rtu"\ndevice_id = 4\n'
        '[drawstring.registers]\naddress = 30\nencoding = "float32_mm"\nword_order = "little"',
        'kind = "ascii"\nport = "{dir}/ds-ascii"\nbaudrate = 115200',
    ],
)
def test_serial_drawstrings_are_served_where_the_config_says(tmp_path, drawstring):
    from sim_fixtures.station_sim import SimStation
    from station.commands.read import read_once
    from station.config import load_station_config

    config = tmp_path / "station.toml"
    config.write_text(
        f'[robot]\nkind = "rtde"\nhost = "127.0.0.{random.randint(2, 250)}"\n'
        f"[drawstring]\n{drawstring.format(dir=tmp_path)}\n"
    )
    cfg = load_station_config(config)
    station = SimStation(cfg, hold=True)
    try:
        address = station.start()[1]
        reading = read_once(cfg.drawstring.build(), cfg.reconnect.backoff())
    except OSError as exc:  # the random RTDE address was taken by a parallel test
        pytest.skip(str(exc))
    finally:
        station.stop()
    assert address["port"] == cfg.drawstring.port
    expected = make_cell(0).true_length_mm(make_cell(0).plan_deg[0])[0]
    assert reading.values["length_mm"] == pytest.approx(expected, abs=0.1)
    assert not (tmp_path / "ds-rtu").exists() and not (tmp_path / "ds-ascii").exists()


def test_a_second_sim_serve_that_cannot_start_leaves_the_first_ones_plan(tmp_path):
    """A second ``sim serve`` on addresses in use overwrote the published plan (another seed's) and,
    ending, withdrew it: the next session followed the wrong plan. Nothing may be written by a
    command that fails to start."""
    plan_path = tmp_path / "published" / "plan.csv"
    with serving(tmp_path, extra_config=FAST_SESSION.format(plan=plan_path)) as (_, config, _):
        published = plan_path.read_text()
        second = run_cli("sim", "serve", "--config", str(config), "--seed", "5")
        assert second.returncode == 1 and "cannot start the simulated devices" in second.stderr
        assert plan_path.read_text() == published
        # the first still serves: every device answers (the dial may say "past the end": the robot
        # walks the plan, between targets on a loaded machine, off the edge: exit 3, its code)
        read = run_cli("read", "--config", str(config))
        values = json.loads(read.stdout)
        assert read.returncode in (0, 3) and len(values["q_deg"]) == 6 and values["length_mm"] > 0
        assert read.returncode == 0 or read.stderr.startswith("station: dial: "), read.stderr
