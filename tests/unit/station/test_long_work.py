"""Long work in a command (issue 21 item 6): ``station calibrate`` says what it is doing on stderr
while it lasts, and refuses, before any work, rows the machine's memory cannot hold (exit 2, one
line naming the samples, nothing written). Time and memory per row: ``benchmarks/calibrate_scaling.py``."""

from __future__ import annotations

import io
import time

import pytest

from errors import InputError
from station.cli import main
from station.commands import calibrate as calibrate_command
from station.commands.long_work import (
    CALIBRATE_BASE_BYTES,
    CALIBRATE_ROW_BYTES,
    Ticker,
    check_calibrate_memory,
)


def _wait_for(predicate, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_the_ticker_says_the_stage_and_the_time_while_work_lasts():
    out = io.StringIO()
    with Ticker("calibrate: 100000 rows", every_s=0.05, stream=out) as ticker:
        ticker.stage("choosing the terms")
        _wait_for(lambda: "choosing the terms" in out.getvalue())
        ticker.stage("fitting (lmlc)")  # once lines began, a new stage is said at once
        assert out.getvalue().splitlines()[-1].startswith("calibrate: 100000 rows: fitting (lmlc), ")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("calibrate: 100000 rows: choosing the terms, ") and lines[0].endswith(
        " s so far"
    )
    after = len(out.getvalue())
    time.sleep(0.2)
    assert len(out.getvalue()) == after  # closed: nothing more


def test_work_done_sooner_than_a_tick_says_nothing():
    out = io.StringIO()
    with Ticker("calibrate: 210 rows", every_s=30.0, stream=out) as ticker:
        ticker.stage("fitting (lmlc)")
    assert out.getvalue() == ""


def test_rows_beyond_the_available_memory_are_refused_naming_what_fits():
    rows = 2_000_000
    need = CALIBRATE_BASE_BYTES + CALIBRATE_ROW_BYTES * rows
    check_calibrate_memory("s.csv", rows, None)  # unknown memory: no refusal
    check_calibrate_memory("s.csv", rows, need)
    with pytest.raises(InputError) as err:
        check_calibrate_memory("s.csv", rows, need // 2)
    text = str(err.value)
    most = (need // 2 - CALIBRATE_BASE_BYTES) // CALIBRATE_ROW_BYTES
    assert text.startswith("s.csv: 2000000 rows need about 14.2 GB") and f"at most about {most} rows" in text


def test_calibrate_refuses_rows_the_memory_cannot_hold_before_any_work(
    three_lines, tmp_path, capsys, monkeypatch
):
    sc = three_lines
    monkeypatch.setattr(calibrate_command, "available_memory_bytes", lambda: CALIBRATE_BASE_BYTES + 1000)
    out = tmp_path / "corrected.toml"
    code = main(
        ["calibrate", str(sc.samples), "--robot", str(sc.robot), "--setup", str(sc.setup), "--out", str(out)]
    )
    _, err = capsys.readouterr()
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert str(sc.samples) in err and "rows need about" in err
    assert not out.exists()
