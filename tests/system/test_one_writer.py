"""Two ``station`` processes on one session folder (issue 20, item 3): one writes it, the other is
refused with "folder in use by PID ..." (exit 2) before it reads or repairs anything, with and
without a dial (whose serial port is the first thing two sessions used to fight over); a command
refused a serial port names the process that holds it."""

from __future__ import annotations

import subprocess
import sys
import time

import tomli_w
import tomllib

from tests.system.test_session import N_TARGETS, ROOT, _lines, rows_of, simulated, write_config


def _station(*args) -> list[str]:
    return [sys.executable, "-m", "station.cli", *map(str, args)]


def _new_session(config, folder) -> subprocess.Popen:
    """``station sample --out folder`` started in the background, its output kept."""
    command = _station("sample", "--config", config, "--out", folder)
    return subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_rows(folder, n: int, proc) -> None:
    deadline = time.monotonic() + 60
    while len(_lines(folder)) < n + 1 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert len(_lines(folder)) >= n + 1, "the first session stored no samples"


def _assert_one_session(folder) -> None:
    rows = rows_of(folder)
    assert [int(r["sample"]) for r in rows] == list(range(N_TARGETS))
    assert sorted(int(r["target"]) for r in rows) == list(range(N_TARGETS))


def test_two_sessions_started_together_on_one_folder_without_a_dial_one_is_refused(tmp_path):
    config = write_config(tmp_path)
    raw = tomllib.loads(config.read_text())
    del raw["dial"]  # nothing exclusive to fight over but the folder
    config.write_text(tomli_w.dumps(raw))
    folder = tmp_path / "sess"
    with simulated(config):
        first = _new_session(config, folder)
        time.sleep(0.3)
        second = subprocess.run(
            _station("sample", "--config", config, "--out", folder), cwd=ROOT, capture_output=True,
            text=True, timeout=120,
        )  # fmt: skip
        out, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    assert second.returncode == 2, second.stdout + second.stderr
    (line,) = second.stderr.splitlines()
    in_use = f"station: error: {folder}: folder in use by PID {first.pid} ("
    made = f"station: error: {folder}: already holds a session; continue it with --resume {folder}"
    assert line.startswith(in_use) or line == made  # the first made it before the second got there
    _assert_one_session(folder)


def test_a_second_writer_with_a_dial_is_refused_before_it_reads_anything(tmp_path):
    config = write_config(tmp_path, time_scale=4.0)  # slow enough to act while it runs
    folder = tmp_path / "sess"
    with simulated(config):
        first = _new_session(config, folder)
        try:
            _wait_rows(folder, 2, first)
            before = {p.name: p.read_bytes() for p in folder.iterdir() if p.suffix == ".csv"}
            read = subprocess.run(
                _station("read", "--config", config), cwd=ROOT, capture_output=True, text=True
            )
            resume = subprocess.run(
                _station("sample", "--resume", folder), cwd=ROOT, capture_output=True, text=True, timeout=60
            )
            again = subprocess.run(
                _station("sample", "--config", config, "--out", folder),
                cwd=ROOT, capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            after = {p.name: p.read_bytes() for p in folder.iterdir() if p.suffix == ".csv"}
            assert first.poll() is None, "the first session ended before the others were refused"
        finally:
            out, err = first.communicate(timeout=120)
    assert first.returncode == 0, err
    for refused in (resume, again):
        assert refused.returncode == 2, refused.stderr
        (line,) = refused.stderr.splitlines()
        assert line.startswith(f"station: error: {folder}: folder in use by PID {first.pid} (")
        assert "sample --config" in line and line.endswith("); nothing in it touched")
    for name, data in before.items():  # the live session's rows untouched (it may have added more)
        assert after[name].startswith(data)
    # the dial's port is the first session's: the refusal names it rather than `station sim serve`
    assert read.returncode == 1
    assert f"({tmp_path / 'dial'} is held by PID {first.pid} ({sys.executable} -m station.cli" in read.stderr
    assert read.stderr.count("\n") == 1 and "station sim serve" not in read.stderr
    _assert_one_session(folder)
