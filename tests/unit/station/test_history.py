"""The history database and ``station history`` under what careless files, shared folders, busy
stations and long lives send (issue 34, items 10-15): every refusal one line and exit 2 with the
file left as it was, a record that cannot be written said on stderr beside the command's own exit,
no record lost, no forged line, a plot of 10,000 records as quick as one of 10."""

import json
import multiprocessing
import os
import re
import shutil
import sqlite3
import subprocess
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path

import pytest

from station import history
from station.cli import main

ROOT = Path(__file__).resolve().parents[3]
DROP = "-dac_override,-dac_read_search,-fowner"
"""The capabilities that let root ignore a folder's mode bits: without them a root process is held
to the owner's bits as any user is (tests here run as root; ``chmod`` alone stops no root)."""


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A small simulated cell (3 lines x 20 poses) and ``station calibrate``'s flags for it."""
    from sim_fixtures.scenario import write_scenario

    s = write_scenario(tmp_path_factory.mktemp("hcell"), seed=3, n_lines=3, n_per_line=20)
    return s, ["--robot", str(s.robot), "--setup", str(s.setup), "--model", "geometric"]


def _calibrate(cell, out: Path, db: Path, robot: Path | None = None) -> int:
    s, flags = cell
    if robot is not None:
        flags = ["--robot", str(robot), *flags[2:]]
    return main(["calibrate", str(s.samples), "--out", str(out), *flags, "--db", str(db)])


def _record(k: int, robot: str = "R1") -> history.Record:
    return history.Record(
        robot, "robot", f"2026-01-01T00:00:{k % 60:02d}+00:00", "verify", f"s{k}", "t", "", "holds", 0.1, {}
    )


def _station_held_to_modes(argv: list, **kwargs) -> subprocess.CompletedProcess:
    """``station ARGV`` in a process of its own that folder modes bind (as root: without ``DROP``)."""
    command = [sys.executable, "-m", "station.cli", *map(str, argv)]
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv: no way to make a folder unreadable to root")
        command = ["setpriv", f"--inh-caps={DROP}", f"--bounding-set={DROP}", *command]
    return subprocess.run(command, capture_output=True, text=True, cwd=ROOT, timeout=120, **kwargs)


def _one_error_line(err: str) -> str:
    assert "Traceback" not in err and err.count("\n") == 1, err
    return err


# item 10: a history of a layout or version this station does not know


def _foreign_layout(db: Path, case: str) -> None:
    """``db``: a history (one record of R1) changed as another program, a hand or a newer station
    would leave it."""
    history.append(db, _record(1))
    conn = sqlite3.connect(db)
    if case == "columns missing":
        conn.executescript(
            "ALTER TABLE records RENAME TO old; CREATE TABLE records (id INTEGER PRIMARY KEY, robot TEXT);"
            "INSERT INTO records (robot) VALUES ('R1'); DROP TABLE old;"
        )
    elif case == "no table":
        conn.executescript("DROP TABLE records;")
    elif case == "figures not JSON":
        conn.execute("UPDATE records SET figures = '{not json'")
    elif case == "a serial of bytes":
        conn.execute("UPDATE records SET robot_name = X'1b5b33316d'")
    else:
        conn.execute("PRAGMA user_version = 7")
    conn.commit()
    conn.close()


@pytest.mark.parametrize(
    "case, says",
    [
        ("columns missing", "table records lacks robot_name, time_utc"),
        ("no table", "(no table records)"),
        ("figures not JSON", "record #1: its figures are not JSON"),
        ("a serial of bytes", "record #1: its robot_name is bytes"),
        ("a newer version", "schema version 7, written by a newer station"),
    ],
)
def test_a_history_this_station_does_not_know_is_refused_in_one_line(tmp_path, capsys, case, says):
    db = tmp_path / "h.sqlite"
    _foreign_layout(db, case)
    before = db.read_bytes()
    assert main(["history", "R1", "--db", str(db)]) == 2
    err = _one_error_line(capsys.readouterr().err)
    assert err.startswith(f"station: error: {db}: ") and says in err
    assert db.read_bytes() == before


def test_a_history_of_a_newer_version_is_not_appended_to(cell, tmp_path, capsys):
    """Before versions, a newer station's history took this one's records silently."""
    db = tmp_path / "h.sqlite"
    _foreign_layout(db, "a newer version")
    before = db.read_bytes()
    assert _calibrate(cell, tmp_path / "t.toml", db) == 0
    err = _one_error_line(capsys.readouterr().err)
    assert err.startswith("station: history not written: ") and "schema version 7" in err
    assert (tmp_path / "t.toml").exists() and db.read_bytes() == before


def test_a_history_made_before_versions_is_read_and_appended_to(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    history.append(db, _record(1))
    conn = sqlite3.connect(db)
    conn.execute("PRAGMA user_version = 0")  # as every history before schema versions
    conn.commit()
    conn.close()
    assert main(["history", "R1", "--db", str(db), "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["records"]) == 1
    history.append(db, _record(2))
    assert len(history.records(db, "R1")) == 2
    assert sqlite3.connect(db).execute("PRAGMA user_version").fetchone()[0] == history.SCHEMA_VERSION


# item 11: a --db folder this user cannot search


def test_a_db_folder_the_user_cannot_search_leaves_each_command_its_own_exit(cell, tmp_path):
    """calibrate and verify keep their result and say "history not written"; history exits 2."""
    s, flags = cell
    locked = tmp_path / "locked"
    locked.mkdir(mode=0)
    db = locked / "h.sqlite"
    try:
        calibrate = _station_held_to_modes(
            ["calibrate", s.samples, "--out", tmp_path / "t.toml", *flags, "--db", db]
        )
        verify = _station_held_to_modes(
            ["verify", s.holdout, "--table", tmp_path / "t.toml", *flags[:4], "--db", db]
        )
        listing = _station_held_to_modes(["history", "--db", db])
    finally:
        locked.chmod(0o755)
    assert calibrate.returncode == 0 and (tmp_path / "t.toml").exists(), calibrate.stderr
    assert verify.returncode in (0, 3), verify.stderr
    for done in (calibrate, verify):
        err = _one_error_line(done.stderr)
        assert (
            err
            == f"station: history not written: {db}: cannot reach the history database (Permission denied)\n"
        )
    assert listing.returncode == 2
    assert _one_error_line(listing.stderr).startswith(f"station: error: {db}: cannot reach the history")
    assert not db.exists()


def test_a_db_that_is_a_folder_is_named_so(cell, tmp_path, capsys):
    """It read as "disk I/O error" (history) and "unable to open database file" (calibrate)."""
    assert main(["history", "--db", str(tmp_path)]) == 2
    says = f"{tmp_path}: a folder; --db names the history's file (e.g. {tmp_path}/history.sqlite)"
    assert _one_error_line(capsys.readouterr().err) == f"station: error: {says}\n"
    assert _calibrate(cell, tmp_path / "t.toml", tmp_path) == 0
    assert "history not written: " + f"{tmp_path}: a folder" in _one_error_line(capsys.readouterr().err)


# item 12: a WAL history in a folder this user cannot write


def test_a_wal_history_in_a_read_only_folder_is_read(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    db = shared / "h.sqlite"
    for k in range(3):
        history.append(db, _record(k))
    assert db.read_bytes()[18:20] == b"\x02\x02"  # the file's header: WAL journal
    shared.chmod(0o555)
    try:
        done = _station_held_to_modes(["history", "R1", "--db", db, "--json"])
    finally:
        shared.chmod(0o755)
    assert done.returncode == 0, done.stderr
    assert [r["samples"] for r in json.loads(done.stdout)["records"]] == ["s0", "s1", "s2"]
    assert sorted(p.name for p in shared.iterdir()) == ["h.sqlite"]


def test_a_read_only_history_with_records_only_in_its_log_is_refused_not_half_read(tmp_path):
    """Copied while a station held it open: ``-wal`` holds records the file does not yet, and no
    ``-shm`` can be made beside it. Read as it lies, the file would lack them."""
    db, shared = tmp_path / "h.sqlite", tmp_path / "shared"
    history.append(db, _record(0))
    writer = sqlite3.connect(db, isolation_level=None)
    writer.execute("PRAGMA wal_autocheckpoint = 0")
    writer.execute("INSERT INTO records SELECT NULL, robot, robot_name, time_utc, command, 's1', "
                   "table_path, table_hash, verdict, rmse_mm, figures FROM records")  # fmt: skip
    shared.mkdir()
    for name in ("h.sqlite", "h.sqlite-wal"):
        shutil.copy(tmp_path / name, shared / name)
    writer.close()
    shared.chmod(0o555)
    try:
        done = _station_held_to_modes(["history", "R1", "--db", shared / "h.sqlite"])
    finally:
        shared.chmod(0o755)
    assert done.returncode == 2
    assert "write-ahead log (h.sqlite-wal) holds records not yet in the file" in _one_error_line(done.stderr)
    assert [r["samples"] for r in history.records(shared / "h.sqlite", "R1")] == ["s0", "s1"]


# item 13: stations making a new history at the same instant


def _writer(db: Path, barrier, base: int, count: int) -> None:
    barrier.wait()
    for k in range(count):
        history.append(db, _record(base + k))


def _at_once(dbs: list[Path], count: int, processes: int = 3) -> list[int]:
    """``processes`` writers, each appending ``count`` records to each of ``dbs`` in turn, all
    starting each database at one instant (a barrier); their exit codes."""
    context = multiprocessing.get_context("fork")
    codes = []
    for db in dbs:
        barrier = context.Barrier(processes)
        writers = [
            context.Process(target=_writer, args=(db, barrier, 1000 * p, count)) for p in range(processes)
        ]
        for w in writers:
            w.start()
        for w in writers:
            w.join(120)
        codes += [w.exitcode for w in writers]
    return codes


def test_three_stations_making_new_histories_at_once_lose_none_of_300_records(tmp_path):
    """The appends of ``station calibrate`` and ``verify`` (``history.append``) from three
    processes, 100 records each, on 50 new databases that all three start at one instant: the
    first check and the WAL switch raced (14 of 300 records lost)."""
    dbs = [tmp_path / f"h{k}.sqlite" for k in range(50)]
    assert _at_once(dbs, 2) == [0] * 150
    each = sorted(f"s{1000 * p + k}" for p in range(3) for k in range(2))
    for db in dbs:
        found = history.records(db, "R1")
        assert sorted(r["samples"] for r in found) == each and len({r["id"] for r in found}) == 6


# item 14: what a robot file or a database holds, shown as one line of what it is


FORGED = "JR680$\\frac$\n  #9999 2030-01-01T00:00:00+00:00  calibrate consistent 0.001 mm  forged\x1b[31m"
"""A serial that, shown as it is, adds a record line, colours the terminal red and is mathtext."""


def test_a_serial_with_newlines_and_escapes_forges_no_line(cell, tmp_path, capsys):
    s, _ = cell
    robot = tmp_path / "robot.toml"
    robot.write_text(f"serial = {json.dumps(FORGED)}\n" + s.robot.read_text())
    db = tmp_path / "h.sqlite"
    assert _calibrate(cell, tmp_path / "t.toml", db, robot) == 0
    capsys.readouterr()
    assert main(["history", "--db", str(db)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and len(out.splitlines()) == 2  # the header and one robot
    assert "JR680$\\frac$\\n  #9999" in out and "forged\\x1b[31m" in out
    assert main(["history", FORGED, "--db", str(db), "--plot", str(tmp_path / "h.png")]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "#9999" not in "".join(line[:4] for line in out.splitlines())
    assert len(out.splitlines()) == 4  # title, one record, no move, wrote
    assert (tmp_path / "h.png").stat().st_size > 0


@pytest.mark.parametrize("key, value", [("serial", ""), ("serial", "   "), ("serial", "\t\n"), ("name", " ")])
def test_a_blank_serial_is_refused_not_made_an_identity(cell, tmp_path, capsys, key, value):
    """A blank serial, or a blank name without a serial, would be a robot's identity."""
    s, _ = cell
    robot = tmp_path / "robot.toml"
    text = s.robot.read_text()
    if key == "name":
        text = re.sub(r'(?m)^name = ".*"$', f"name = {json.dumps(value)}", text)
    robot.write_text((f"serial = {json.dumps(value)}\n" if key == "serial" else "") + text)
    db = tmp_path / "h.sqlite"
    assert _calibrate(cell, tmp_path / "t.toml", db, robot) == 2
    err = _one_error_line(capsys.readouterr().err)
    assert str(robot) in err and key in err
    assert not db.exists() and not (tmp_path / "t.toml").exists()


# item 15: the plot of a long history


COLUMNS = "robot, robot_name, time_utc, command, samples, table_path, table_hash, verdict, rmse_mm, figures"


def _long_history(db: Path, count: int) -> None:
    """``count`` records of R1, 6 h apart: a calibration every fourth, else verifications."""
    history.append(db, _record(0))
    start = datetime(2026, 1, 1, tzinfo=timezone.utc)
    rows = [
        ("R1", "robot", (start + timedelta(hours=6 * k)).isoformat(), "calibrate" if k % 4 == 0 else "verify",
         f"s{k}", "t", "", "consistent" if k % 4 == 0 else "holds", 0.02 + 0.001 * (k % 7), "{}")
        for k in range(1, count)
    ]  # fmt: skip
    conn = sqlite3.connect(db)
    with conn:
        conn.executemany(f"INSERT INTO records ({COLUMNS}) VALUES ({', '.join('?' * 10)})", rows)
    conn.close()


def test_the_plot_of_a_long_history_draws_each_series_at_once_with_dates_that_do_not_overlap(
    tmp_path, monkeypatch
):
    """300 records: one ``plot`` call a point (14 s for 1,000 records, 120 s and 687 MB for 10,000)
    and a tick label a record, overlapping from 100 on. Checked in the figure the command saves."""
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    db = tmp_path / "h.sqlite"
    _long_history(db, 300)
    calls, boxes = [], []
    plot, savefig = Axes.plot, Figure.savefig

    def counted(ax, *args, **kwargs):
        calls.append(len(args[0]) if args and hasattr(args[0], "__len__") else 1)
        return plot(ax, *args, **kwargs)

    def saved(fig, *args, **kwargs):
        savefig(fig, *args, **kwargs)  # lays the tick labels out
        renderer = fig.canvas.get_renderer()
        labels = [t for t in fig.axes[0].get_xticklabels() if t.get_visible() and t.get_text()]
        boxes.extend(sorted((b.x0, b.x1) for b in (t.get_window_extent(renderer) for t in labels)))

    monkeypatch.setattr(Axes, "plot", counted)
    monkeypatch.setattr(Figure, "savefig", saved)
    assert main(["history", "R1", "--db", str(db), "--plot", str(tmp_path / "h.png")]) == 0
    assert len(calls) <= 8 and sum(calls) >= 300  # every record drawn, in a few calls
    assert 3 <= len(boxes) <= 15
    assert all(left[1] < right[0] for left, right in zip(boxes[:-1], boxes[1:], strict=True))
