"""``station sample`` against the simulated devices (real drivers, real protocols): the capture rule
against the simulated truth, the session folder, the .rrd, and the faults of issue 5.

Each test starts its own simulated station on non-contract addresses (RTDE on a random
127.0.0.x, Modbus on a free port, the dial's pty link in tmp_path), with 3 targets per line and
simulated time 30x, so a whole session takes a second or two.
"""

from __future__ import annotations

import contextlib
import csv
import os
import random
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from rerun.chunk import RrdReader

import configs
from sim_fixtures.robot_program import RobotFault
from sim_fixtures.station_sim import SimStation, make_cell
from station import cli
from station.acquire import runner
from station.acquire.session import State
from station.commands.sim import publish_plan
from station.config import StationConfig
from station.formats.plan import Plan
from station.formats.samples import load_samples
from station.formats.session_folder import load_session
from station.formats.tables import load_robot, load_setup
from station.jobs import planning

ROOT = Path(__file__).resolve().parents[2]
PER_LINE = 3
N_TARGETS = 3 * PER_LINE
K = 5  # readings per capture (default rule)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_config(folder: Path, per_line: int = PER_LINE, time_scale: float = 30.0, **session) -> Path:
    raw = {
        "time_scale": time_scale,
        "robot": {"kind": "rtde", "host": f"127.0.0.{random.randint(2, 250)}"},
        "drawstring": {"kind": "modbus_tcp", "port": _free_port()},
        "dial": {"port": str(folder / "dial")},
        "reconnect": {"attempts": 2, "initial_s": 0.05},
        "session": {"plan": str(folder / "plan.csv"), **session},
        "sim": {
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 2.0,
            "targets_per_line": per_line,
            "plan_csv": str(folder / "plan.csv"),
        },
    }
    path = folder / "station.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


@contextlib.contextmanager
def simulated(config: Path, faults=(), plan=None):
    raw = __import__("tomllib").loads(config.read_text())
    cfg = StationConfig.model_validate(raw)
    sim = SimStation(cfg, faults=faults, plan=plan)
    if plan is None:
        publish_plan(Path(cfg.sim.plan_csv), Plan.of(sim.plan_deg, sim.plan_lines))
    sim.start()
    try:
        yield sim
    finally:
        sim.stop()


def rows_of(folder: Path) -> list[dict]:
    with (folder / "samples.csv").open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """One whole session, run in-process: (session folder, messages)."""
    tmp = tmp_path_factory.mktemp("session")
    config = write_config(tmp)
    messages = []
    with simulated(config):
        inputs = runner.new_session(tmp / "sess", config, None)
        done = runner.run(inputs, stream=_Sink(messages))
        done.view.close()
        state = done.state
    assert state is State.DONE
    return tmp / "sess", messages


class _Sink:
    """A non-terminal output stream that keeps what was written."""

    def __init__(self, into: list):
        self.into = into

    def isatty(self) -> bool:
        return False

    def write(self, text: str) -> None:
        self.into.append(text)

    def flush(self) -> None:
        pass


def test_every_target_once_and_readings_match_the_simulated_truth(finished):
    folder, _ = finished
    rows = rows_of(folder)
    assert sorted(int(r["target"]) for r in rows) == list(range(N_TARGETS))
    assert [int(r["sample"]) for r in rows] == list(range(N_TARGETS))
    assert_readings_match_the_truth(rows)
    spreads = np.array([float(r["length_spread_mm"]) for r in rows])
    assert 0 < np.median(spreads) < 3 * make_cell(0, PER_LINE).world.noise.length_mm


def assert_readings_match_the_truth(rows: list[dict]) -> None:
    """Every stored length and dial reading is the simulated truth at its joints, within noise."""
    world = make_cell(0, PER_LINE).world
    q = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in rows])
    lines = np.array([int(r["line"]) for r in rows])
    # Means of K readings: 5 standard errors of the mean, plus half the 1 um resolution.
    length_err = np.array([float(r["length_mm"]) for r in rows]) - world.true_length_mm(q)
    dial_err = np.array([float(r["dial_mm"]) for r in rows]) - world.true_dial_mm(q, lines)
    assert np.max(np.abs(length_err)) < 5 * world.noise.length_mm / np.sqrt(K) + 0.0005
    assert np.max(np.abs(dial_err)) < 5 * world.noise.dial_mm / np.sqrt(K) + 0.0005


def test_a_designed_plan_is_walked_and_measured_target_by_target(tmp_path):
    # station plan -> sim serve --plan -> station sample --plan: each planned target once, each
    # capture near its planned pose (the robot touched the true edge there).
    robot, setup = (
        load_robot(configs.path("robots/hsr_jr680.toml")),
        load_setup(configs.path("setups/sim.toml")),
    )
    plan = planning.design(robot, setup, per_line=14, n_select=36, suggest=False).plan
    plan_path = tmp_path / "plan.csv"
    plan_path.write_text(plan.csv_text())
    config = write_config(tmp_path)
    with simulated(config, plan=(plan.q_deg, plan.line)):
        inputs = runner.new_session(tmp_path / "sess", config, plan_path)
        messages = []
        done = runner.run(inputs, stream=_Sink(messages))
        done.view.close()
        state = done.state
    assert state is State.DONE, messages
    rows = rows_of(tmp_path / "sess")
    targets = np.array([int(r["target"]) for r in rows])
    assert sorted(targets) == list(range(len(plan)))
    q = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in rows])
    assert np.abs(q - plan.q_deg[targets]).max() < 2.0  # robot errors: a fraction of a degree


def test_session_folder_loads_for_calibration_with_every_reading(finished):
    folder, _ = finished
    robot, setup, samples_path = load_session(folder)
    assert robot.name == "HSR-JR680" and setup.drawstring is not None
    assert len(load_samples(samples_path)) == N_TARGETS
    with (folder / "raw.csv").open(newline="") as fh:
        raw = list(csv.DictReader(fh))
    assert len(raw) == K * N_TARGETS
    stamps = np.array([[float(r["t_robot_s"]), float(r["t_length_s"]), float(r["t_dial_s"])] for r in raw])
    assert np.all(np.diff(stamps.ravel()) >= 0)  # robot, drawstring, dial, in turn, round after round


def test_rrd_holds_the_live_view_entities(finished):
    folder, _ = finished
    chunks = RrdReader(folder / "session.rrd").stream().to_chunks()
    entities = {c.entity_path for c in chunks}
    for path in (
        "/cell/anchor",
        "/cell/lines/0",
        "/cell/lines/2",
        "/cell/path",
        "/cell/sample",
        "/cell/cable",
        "/live/length/reading",
        "/live/length/model",
        "/live/error",
        "/live/dial",
        "/log",
        "/cell/base",
        "/cell/robot/links",
        "/cell/robot/joints",
        "/cell/robot/tool",
        "/progress",
    ):
        assert path in entities
    rows = sum(c.num_rows for c in chunks if c.entity_path == "/live/error" and not c.is_static)
    assert rows == 0  # 9 samples cannot determine the running calibration's 26 unknowns: no live error
    # the view counts the samples, and its log's last line names the recording to replay
    assert _texts(chunks, "/progress")[-1].startswith(f"**{N_TARGETS} of {N_TARGETS} samples** (100 %)")
    rrd = folder / "session.rrd"
    assert _texts(chunks, "/log")[-1] == f"session over; replay it with: rerun {rrd}"


def _texts(chunks, entity: str) -> list[str]:
    """The texts logged to ``entity`` (TextLog or TextDocument), in the order logged."""
    out = []
    for chunk in chunks:
        if chunk.entity_path != entity or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        column = next(n for n in batch.schema.names if n.endswith(":text"))
        out += [v[0] for v in batch.column(batch.schema.names.index(column)).to_pylist()]
    return out


def test_sigkill_mid_session_then_resume_without_torn_or_duplicate_rows(tmp_path):
    config = write_config(tmp_path)
    folder = tmp_path / "sess"
    with simulated(config):
        cmd = [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--out", str(folder)]
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and len(_lines(folder)) < 4:
                time.sleep(0.01)
            proc.send_signal(signal.SIGKILL)
        finally:
            proc.wait(10)
        taken = len(rows_of(folder))
        assert 3 <= taken < N_TARGETS
        with (folder / "samples.csv").open("a") as fh:
            fh.write("99,7,2,1.0,2.0")  # a row torn by a power cut mid-write
        inputs = runner.resume_session(folder, None)
        assert len(inputs.folder.rows) == taken
        done = runner.run(inputs, stream=_Sink([]))
        done.view.close()
    assert done.state is State.DONE
    rows = rows_of(folder)
    assert [int(r["sample"]) for r in rows] == list(range(N_TARGETS))
    assert sorted(int(r["target"]) for r in rows) == list(range(N_TARGETS))
    assert all(len(line.split(",")) == len(_lines(folder)[0].split(",")) for line in _lines(folder))


def _lines(folder: Path) -> list[str]:
    path = folder / "samples.csv"
    return path.read_text().splitlines() if path.exists() else []


def session_with(tmp_path, act) -> tuple[State, str]:
    """A session on the simulated devices, run in a thread; once 2 samples are stored,
    ``act(sim, folder, messages)`` does something to the cell. The end state and the log."""
    config = write_config(tmp_path)
    messages: list[str] = []
    with simulated(config) as sim:
        inputs = runner.new_session(tmp_path / "sess", config, None)
        result = {}
        worker = threading.Thread(
            target=lambda: result.update(out=runner.run(inputs, stream=_Sink(messages)))
        )
        worker.start()
        deadline = time.monotonic() + 30
        while len(inputs.folder.rows) < 2 and time.monotonic() < deadline:
            time.sleep(0.005)
        act(sim, inputs.folder, messages)
        worker.join(30)
    done = result["out"]
    done.view.close()
    return done.state, "".join(messages)


def unplug(device: str, says: str):
    """Unplug ``device`` until the log ``says`` so; nothing is recorded meanwhile; replug it."""

    def act(sim, folder, messages):
        sim.devices[device].unplug()
        deadline = time.monotonic() + 30
        while not any(says in m for m in messages) and time.monotonic() < deadline:
            time.sleep(0.01)
        unplugged_rows = len(folder.rows)
        time.sleep(0.3)
        assert len(folder.rows) == unplugged_rows  # nothing recorded while it is gone
        sim.devices[device].replug()

    return act


def test_unplugged_dial_suspends_the_session_which_continues_after_replug(tmp_path):
    state, log = session_with(tmp_path, unplug("dial", "suspended: dial not answering"))
    assert "suspended: dial not answering" in log and "resumed" in log
    assert state is State.DONE and len(rows_of(tmp_path / "sess")) == N_TARGETS


def test_unplugged_modbus_drawstring_suspends_the_session_which_continues_after_replug(tmp_path):
    # Modbus TCP: the connection is reset and new ones refused until the cable is back
    state, log = session_with(tmp_path, unplug("drawstring", "suspended: drawstring not answering"))
    assert "drawstring: link lost to 127.0.0.1" in log  # the fault, named as it happened
    assert "suspended: drawstring not answering: unreachable after 2 attempts" in log and "resumed" in log
    assert state is State.DONE and len(rows_of(tmp_path / "sess")) == N_TARGETS
    assert_readings_match_the_truth(rows_of(tmp_path / "sess"))


def test_a_slack_cable_suspends_the_session_and_no_slack_reading_is_stored(tmp_path):
    # the cable off the tool for 1 s (real): the robot visits a few targets meanwhile
    state, log = session_with(tmp_path, lambda sim, folder, messages: sim.slacken(1.0))
    assert re.search(r"drawstring reads? \d+\.\d+ mm, outside 50\.\.5000 mm: cable slack or jump", log), log
    assert state is State.DONE and len(rows_of(tmp_path / "sess")) == N_TARGETS
    assert_readings_match_the_truth(rows_of(tmp_path / "sess"))


def test_robot_that_never_settles_times_out_with_a_clear_message(tmp_path, capsys):
    config = write_config(tmp_path, target_timeout_s=30.0)  # simulated s: 1 s at 30x
    with simulated(config, faults=[RobotFault(0.0, 1e9, jitter_deg=0.05)]):
        code = cli.main(["sample", "--config", str(config), "--out", str(tmp_path / "sess")])
    out = capsys.readouterr().out
    assert code == 1
    assert "no capture for 30 s: the robot never settled" in out
    assert _lines(tmp_path / "sess") == [_lines(tmp_path / "sess")[0]]  # header kept, nothing torn


def test_read_only_output_folder_fails_before_any_device_is_touched(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    target = ro / "sess" if not os.access(ro, os.W_OK) else Path("/sys/station-test-session")  # root: a ro fs
    config = write_config(tmp_path)  # no simulated devices at all: they must not be needed
    (tmp_path / "plan.csv").write_text(Plan.of(np.zeros((1, 6)), [0]).csv_text())
    code = cli.main(["sample", "--config", str(config), "--out", str(target)])
    err = capsys.readouterr().err
    assert code == 2
    assert f"{target}: cannot write the session folder" in err
    assert "Traceback" not in err


def test_ctrl_c_stops_after_the_sample_in_flight_with_exit_130(tmp_path):
    config = write_config(tmp_path)
    folder = tmp_path / "sess"
    with simulated(config):
        cmd = [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--out", str(folder)]
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and len(_lines(folder)) < 3:
                time.sleep(0.01)
            proc.send_signal(signal.SIGINT)
            out, _ = proc.communicate(timeout=20)
        finally:
            proc.kill()
    assert proc.returncode == 130, out
    assert "stopped: stopped on request" in out
    rows = rows_of(folder)
    assert 2 <= len(rows) < N_TARGETS
    assert len({r["target"] for r in rows}) == len(rows)
    assert _lines(folder)[-1] == (folder / "samples.csv").read_text().rstrip("\n").split("\n")[-1]


def test_progress_is_a_bar_on_a_terminal_with_the_live_error_and_the_predicted_workspace_error():
    from station.acquire.livefit import LiveError
    from station.acquire.progress import Progress

    written: list[str] = []
    tty = _Sink(written)
    tty.isatty = lambda: True
    bar = Progress(total=4, stream=tty, width=8)
    bar.sample({"sample": 0, "target": 0, "line": 0, "length_mm": 1.0}, LiveError())
    bar.sample({"sample": 1, "target": 1, "line": 0, "length_mm": 1.0}, LiveError(fitted=1, needed=26))
    bar.sample({"sample": 2, "target": 2, "line": 0, "length_mm": 1.0}, LiveError(1.0, 0.25, 0.1))
    bar.refit(0.0412, 0.0688)
    bar.message("suspended: dial not answering")
    assert written[0].startswith("\r\033[K[##......] 1/4")
    assert written[0].endswith("error: none until the model is determined (first fit under way)")
    assert written[1].endswith("error: none until the model is determined (1 of 26 samples)")
    assert "error +0.250 mm (limit 0.100)" in written[2]
    assert written[3].endswith("error +0.250 mm (limit 0.100)  workspace 0.0412 mm (95 %: 0.0688 mm)")
    assert written[4].startswith("\r\033[Ksuspended: dial not answering\n[######..] 3/4")


def test_until_mm_ends_the_session_done_once_the_bound_is_met_and_a_resume_measures_the_rest(tmp_path):
    # simulated time only 5x: the refits (worker process) keep up on a loaded 2-core machine
    config = write_config(tmp_path, per_line=12, time_scale=5.0)
    folder = tmp_path / "sess"
    sample = [sys.executable, "-m", "station.cli", "sample", "--config", str(config)]
    with simulated(config):
        first = subprocess.run(
            [*sample, "--out", str(folder), "--until-mm", "3"], capture_output=True, text=True, timeout=300
        )
        assert first.returncode == 0, first.stdout + first.stderr
        taken = len(rows_of(folder))
        assert "done: accuracy reached;" in first.stdout and taken < 36
        assert first.stdout.splitlines()[-1].startswith(f"saved: {taken}/36 samples")
        said = next(line for line in first.stdout.splitlines() if line.startswith("accuracy reached:"))
        assert float(said.split("95 % bound ")[1].split(" mm")[0]) <= 3.0
        # a resume without --until-mm measures the rest of the plan, saying the goal is not carried over
        second = subprocess.run(
            [*sample, "--resume", str(folder)],
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert second.returncode == 0, second.stdout + second.stderr
    assert second.stdout.splitlines()[0] == (
        f"resuming {folder}: {taken} of 36 targets measured; measuring the rest of the plan (the "
        "session's earlier --until-mm 3 is not carried over: give --until-mm again to stop at a goal)"
    )
    rows = rows_of(folder)
    assert [int(r["sample"]) for r in rows] == list(range(36))
    assert sorted(int(r["target"]) for r in rows) == list(range(36))
    assert second.stdout.splitlines()[-1].startswith("saved: 36/36 samples")
    # the resumed recording holds the whole session: the first run's live errors and the new ones
    chunks = RrdReader(folder / "session.rrd").stream().to_chunks()
    logged = sum(c.num_rows for c in chunks if c.entity_path == "/live/length/reading" and not c.is_static)
    assert logged == 36
    assert not (folder / "session.previous.rrd").exists()
