"""A disk that fills during a session, emulated with a file-size limit (``RLIMIT_FSIZE``, SIGXFSZ
ignored: a write past it fails with EFBIG, or writes short) in a child process: the session stops
with one line and exit 1, every file ends with a whole row, ``session.toml`` stays whole, and
``--resume`` continues once there is room."""

from __future__ import annotations

import multiprocessing
import resource
import signal
import subprocess
import sys
from pathlib import Path

import tomli_w
import tomllib

from errors import OutputError
from station import cli
from station.formats.session_folder import RAW_COLUMNS, SAMPLE_COLUMNS, SessionFolder
from tests.system.test_session import ROOT, K, rows_of, simulated, write_config

PER_LINE = 10  # 30 targets: raw.csv passes LIMIT around the 15th sample
LIMIT = 12_000  # bytes a file may grow to


def limit_file_size(limit: int = LIMIT) -> None:
    """In the child: writes past ``limit`` bytes fail (EFBIG) instead of killing the process."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


def test_a_full_disk_stops_the_session_with_one_line_and_resume_continues(tmp_path):
    config = write_config(tmp_path)
    raw = tomllib.loads(config.read_text())
    raw["sim"]["targets_per_line"] = PER_LINE
    config.write_text(tomli_w.dumps(raw))
    folder = tmp_path / "sess"
    cmd = [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--out", str(folder)]
    with simulated(config):
        full = subprocess.run(
            cmd, cwd=ROOT, preexec_fn=limit_file_size, capture_output=True, text=True, timeout=120
        )
        kept = rows_of(folder)
        stored = folder.joinpath("samples.csv").read_text(), folder.joinpath("raw.csv").read_text()
        assert cli.main(["sample", "--resume", str(folder)]) == 0  # room again
    assert full.returncode == 1, full.stderr
    assert full.stderr == (
        f"station: cannot write: {folder}: cannot store sample {len(kept)} (File too large); the "
        f"{len(kept)} samples before it are kept: make room, then continue with --resume {folder}\n"
    )
    assert 5 < len(kept) < 3 * PER_LINE
    for text, columns, rows in (
        (stored[0], SAMPLE_COLUMNS, len(kept)),
        (stored[1], RAW_COLUMNS, K * len(kept)),
    ):
        lines = text.split("\n")
        assert lines[-1] == "" and len(lines) == rows + 2  # header, whole rows, nothing torn
        assert all(len(line.split(",")) == len(columns) for line in lines[:-1])
    rows = rows_of(folder)
    assert [int(r["sample"]) for r in rows] == list(range(3 * PER_LINE))
    assert sorted(int(r["target"]) for r in rows) == list(range(3 * PER_LINE))
    assert rows[: len(kept)] == kept


def test_a_recording_cut_short_by_a_full_disk_is_named_and_every_sample_kept(tmp_path):
    config = write_config(tmp_path)  # 9 targets: the CSV files stay below LIMIT, the .rrd does not
    folder = tmp_path / "sess"
    cmd = [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--out", str(folder)]
    with simulated(config):
        proc = subprocess.run(
            cmd, cwd=ROOT, preexec_fn=limit_file_size, capture_output=True, text=True, timeout=120
        )
    assert proc.returncode == 1
    assert proc.stderr.startswith(f"station: cannot write: {folder / 'session.rrd'}: the recording could not")
    assert proc.stderr.endswith(f"the 9 samples in {folder / 'samples.csv'} are whole\n")
    assert proc.stderr.count("\n") == 1  # Rerun's own log lines about its file sink are kept quiet
    assert sorted(int(r["target"]) for r in rows_of(folder)) == list(range(9))


def _in_child(work, *args):
    """``work(*args)`` in a forked child under the file-size limit; its result (or error text)."""
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()

    def child():
        limit_file_size()
        try:
            queue.put(work(*args))
        except OutputError as exc:
            queue.put(f"OutputError: {exc}")

    process = ctx.Process(target=child)
    process.start()
    result = queue.get(timeout=60)
    process.join(10)
    return result


def _row(k: int) -> dict:
    q = {f"q{i}_deg": 10.0 * i for i in range(1, 7)}
    return {"sample": k, "target": k, "line": 0, **q, "length_mm": 1000.0 + k, "t_s": 0.1 * k}


def _append_until_full(path: Path) -> int:
    folder = SessionFolder.open(path)
    for k in range(10_000):
        folder.append(_row(k), [{"sample": k, "k": j, "length_mm": 1000.0 + k} for j in range(K)])
    return -1


def _new_folder(path: Path) -> None:
    SessionFolder.create(path, {"start_wall_s": 1.7e9, "station": {"time_scale": 1.0}})


def test_an_append_that_fails_part_way_is_taken_back_and_the_folder_goes_on(tmp_path):
    path = tmp_path / "sess"
    _new_folder(path)
    message = _in_child(_append_until_full, path)
    assert message.startswith(f"OutputError: {path}: cannot store sample ") and "File too large" in message
    stored = int(message.split("cannot store sample ")[1].split()[0])
    for name in ("samples.csv", "raw.csv"):
        assert (path / name).read_text().endswith("\n")
    folder = SessionFolder.open(path)  # the file-size limit gone: room again
    assert folder.next_sample == stored and len(folder.raw_csv.read_text().splitlines()) == 1 + K * stored
    folder.append(_row(stored), [])
    assert SessionFolder.open(path).next_sample == stored + 1


def _grow_header(path: Path) -> str:
    SessionFolder.open(path).update_header(notes="x" * 2 * LIMIT)
    return "written"


def test_a_session_toml_update_that_fails_keeps_the_previous_one_whole(tmp_path):
    path = tmp_path / "sess"
    _new_folder(path)
    before = (path / "session.toml").read_text()
    message = _in_child(_grow_header, path)
    assert message.startswith(f"OutputError: {path / 'session.toml'}: cannot update (File too large); ")
    assert (path / "session.toml").read_text() == before
    names = sorted(p.name for p in path.iterdir())
    assert names == ["raw.csv", "samples.csv", "session.lock", "session.toml"]  # no temporary file
