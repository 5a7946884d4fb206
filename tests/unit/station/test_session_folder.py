"""A session folder reopened for ``--resume`` and a plan read back: every value is validated
before anything is repaired, and a problem is one line naming the file, the row or key."""

import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
import tomli_w
import tomllib

from errors import InputError
from station.acquire import runner
from station.formats.plan import Plan, load_plan
from tests.hostile_inputs import absent_devices

PLAN = Plan.of(np.tile([10.0, -30.0, 40.0, 0.0, 20.0, 5.0], (3, 1)) + np.arange(3)[:, None], [0, 0, 1])


@pytest.fixture
def session(tmp_path):
    """A session folder of 2 samples (of 3 targets), with a torn last row in samples.csv."""
    config = tmp_path / "station.toml"
    config.write_text(tomli_w.dumps(absent_devices()))
    (tmp_path / "plan.csv").write_text(PLAN.csv_text())
    inputs = runner.new_session(tmp_path / "sess", config, tmp_path / "plan.csv")
    inputs.folder.make()  # a session run makes it once the devices answer
    for k in range(2):
        q = {f"q{i + 1}_deg": float(v) for i, v in enumerate(PLAN.q_deg[k])}
        row = {"sample": k, "target": k, "line": 0, **q, "length_mm": 900.0 + k, "dial_mm": 0.1, "t_s": k}
        row["t_wall_s"] = 1.7e9 + k
        inputs.folder.append(row, [{"sample": k, "k": 0, **q}])
    inputs.folder.release()  # as the session's process ended
    with (tmp_path / "sess" / "samples.csv").open("a") as fh:
        fh.write("2,2,1,1.0,2.0")
    return tmp_path / "sess"


def _files(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


def _edit_rows(path, row, column, value):
    """Set one cell of a CSV, keeping every other byte (a torn last row stays torn)."""
    lines = path.read_text().split("\n")
    cells = lines[row + 1].split(",")
    cells[lines[0].split(",").index(column)] = value
    lines[row + 1] = ",".join(cells)
    path.write_text("\n".join(lines))


def test_a_resumed_session_is_repaired_and_continues_after_its_last_whole_row(session):
    inputs = runner.resume_session(session, None)
    assert [r["sample"] for r in inputs.folder.rows] == ["0", "1"]
    assert inputs.folder.next_sample == 2 and inputs.folder.finished_targets == {0, 1}
    assert (session / "samples.csv").read_text().endswith("\n")  # the torn row is cut


@pytest.mark.parametrize(
    "file, row, column, value, message",
    [
        ("samples.csv", 1, "target", "abc", "samples.csv: row 1 (line 3): target: 'abc' is not a target id"),
        (
            "samples.csv",
            0,
            "q4_deg",
            "inf",
            "samples.csv: row 0 (line 2): q4_deg: 'inf' is not a finite number",
        ),
        ("samples.csv", 1, "t_s", "", "samples.csv: row 1 (line 3): t_s: '(empty)' is not a finite number"),
        ("raw.csv", 0, "sample", "-1", "raw.csv: row 0 (line 2): sample: '-1' is not a sample id"),
    ],
)
def test_a_bad_cell_is_named_and_nothing_is_repaired(session, file, row, column, value, message):
    _edit_rows(session / file, row, column, value)
    before = _files(session)
    with pytest.raises(InputError, match=re.escape(message)):
        runner.resume_session(session, None)
    assert _files(session) == before  # the torn row is still there: nothing touched


@pytest.mark.parametrize(
    "key, value, message",
    [
        (
            ("robot", "joints", 0, "a_mm"),
            float("nan"),
            r"session\.toml: robot\.joints\.0\.a_mm: Input should be a fin",
        ),
        (("start_wall_s",), "yesterday", r"session\.toml: start_wall_s: Input should be a valid number"),
        (
            ("plan", 1, "q_deg", 2),
            float("inf"),
            r"session\.toml: plan\.1\.q_deg\.2: Input should be a finite",
        ),
        (("plan", 2, "target"), 0, r"session\.toml: target id 0 appears twice"),
        (
            ("station", "reconnect", "attempts"),
            0,
            r"session\.toml \[station\]: reconnect\.attempts: Input should",
        ),
    ],
)
def test_a_bad_session_toml_is_named_and_nothing_is_repaired(session, key, value, message):
    header = tomllib.loads((session / "session.toml").read_text())
    node = header
    for k in key[:-1]:
        node = node[k]
    node[key[-1]] = value
    (session / "session.toml").write_text(tomli_w.dumps(header))
    before = _files(session)
    with pytest.raises(InputError, match=message):
        runner.resume_session(session, None)
    assert _files(session) == before


@pytest.mark.parametrize(
    "row, column, value, message",
    [
        (0, "target", "inf", "row 0 (line 2): target: 'inf' is not a target id"),
        (1, "target", "1.5", "row 1 (line 3): target: '1.5' is not a target id"),
        (2, "target", "0", "target id 0 appears twice"),
        (1, "line", "-1", "row 1 (line 3): line: '-1' is not a line id"),
        (2, "q5_deg", "1e308", "row 2 (line 4): q5_deg: '1e308' is outside -3600 .. 3600 deg"),
    ],
)
def test_a_bad_plan_cell_is_named(tmp_path, row, column, value, message):
    path = tmp_path / "plan.csv"
    path.write_text(PLAN.csv_text())
    _edit_rows(path, row, column, value)
    with pytest.raises(InputError, match=re.escape(message)):
        load_plan(path)


def test_a_copied_session_resumes_where_its_rows_end(session, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(session, copy)
    assert runner.resume_session(copy, None).folder.next_sample == 2


def test_a_new_session_folder_is_written_only_when_made(tmp_path):
    from station.formats.session_folder import SessionFolder

    folder = SessionFolder.new(tmp_path / "runs" / "today" / "run1", {"start_wall_s": 1.7e9})
    folder.update_header(until_mm=0.5)
    assert not (tmp_path / "runs").exists()
    folder.make()
    written = tomllib.loads((folder.path / "session.toml").read_text())
    assert written == {"start_wall_s": 1.7e9, "until_mm": 0.5}
    assert (folder.samples_csv.read_text().count("\n"), folder.raw_csv.read_text().count("\n")) == (1, 1)
    with pytest.raises(InputError, match="already holds a session; continue it with --resume"):
        SessionFolder.new(folder.path, {})
    (tmp_path / "file").write_text("")
    with pytest.raises(InputError, match=r"cannot write the session folder: .*file is not a folder"):
        SessionFolder.new(tmp_path / "file" / "run1", {})


def test_a_whole_last_row_without_its_newline_is_kept_and_a_torn_one_dropped_and_said(session):
    samples = session / "samples.csv"
    text = samples.read_text()
    whole = text[: text.rindex("\n")]  # the torn row gone, and the newline of the last whole row
    samples.write_text(whole)
    inputs = runner.resume_session(session, None)
    assert [r["sample"] for r in inputs.folder.rows] == ["0", "1"]
    assert inputs.folder.next_sample == 2 and samples.read_text() == whole + "\n"
    assert any("last row had no newline at the end; the row is whole and kept" in n for n in inputs.notes)
    inputs.folder.release()
    samples.write_text(whole[:-3])  # the last row torn inside its last cell: all fields, cut short
    inputs = runner.resume_session(session, None)
    assert [r["sample"] for r in inputs.folder.rows] == ["0"]
    assert any("a torn last row was dropped" in n for n in inputs.notes)


@pytest.mark.parametrize(
    "row, column, value, message",
    [
        (1, "target", "7", "samples.csv: row 1 (line 3): target 7 is not in the session's plan (3 targets)"),
        (1, "line", "1", "samples.csv: row 1 (line 3): line 1, but target 1 is on line 0 in the plan"),
        (1, "sample", "0", "samples.csv: row 1 (line 3): sample id 0 again (row 0)"),
        (1, "target", "0", "samples.csv: row 1 (line 3): target 0 measured again (row 0)"),
    ],
)
def test_a_row_the_plan_does_not_hold_is_named_by_resume_and_calibrate(session, row, column, value, message):
    from station.cli import build_parser
    from station.commands.calibrate import load_inputs

    _edit_rows(session / "samples.csv", row, column, value)
    before = _files(session)
    with pytest.raises(InputError, match=re.escape(message)):
        runner.resume_session(session, None)
    assert _files(session) == before
    args = build_parser().parse_args(["calibrate", str(session), "--out", str(session.parent / "t.toml")])
    with pytest.raises(InputError, match=re.escape(message)):
        load_inputs(args)


def test_a_folder_another_process_writes_is_refused_before_anything_is_read(session):
    holder = subprocess.Popen(  # another writer: holds the folder's lock until told to go
        [sys.executable, "-c", HOLD, str(session)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline() == "locked\n"
        (session / "session.toml").write_text("not toml [")  # read before locking: another error
        before = _files(session)
        in_use = rf"sess: folder in use by PID {holder.pid} \(.*-c.*\); nothing in it touched"
        with pytest.raises(InputError, match=in_use):
            runner.resume_session(session, None)
        assert _files(session) == before
    finally:
        holder.communicate("", timeout=10)
    with pytest.raises(InputError, match="session.toml: not valid TOML"):
        runner.resume_session(session, None)


HOLD = """
import sys
from station.formats.session_folder import FolderLock
lock = FolderLock.take(sys.argv[1])
print("locked", flush=True)
sys.stdin.read()
"""
