"""A session folder whose name is not UTF-8 (named on a system with another encoding, issue 21
item 9): ``station sample`` records into it (the Rerun recording id takes the name shown with
``\\xNN``) and ``station calibrate`` calibrates it, both printing the name as it is."""

from __future__ import annotations

import os
import subprocess
import sys

import tomllib

from tests.system.test_session import ROOT, rows_of, simulated, write_config


def test_a_session_in_a_folder_named_in_another_encoding_is_recorded_and_calibrated(tmp_path):
    config = write_config(tmp_path, per_line=12)  # 36 samples: enough to calibrate
    folder = tmp_path / os.fsdecode(b"sitzung-\xe4")  # latin-1 "ä": not UTF-8
    with simulated(config):
        sample = subprocess.run(
            [sys.executable, "-m", "station.cli", "sample", "--config", str(config), "--out", str(folder)],
            cwd=ROOT, capture_output=True, timeout=120,
        )  # fmt: skip
    assert sample.returncode == 0, sample.stderr.decode(errors="replace")
    assert sample.stdout.splitlines()[-1].startswith(b"saved: 36/36 samples in " + os.fsencode(folder))
    assert len(rows_of(folder)) == 36 and (folder / "session.rrd").stat().st_size > 0
    calibrate = subprocess.run(
        [sys.executable, "-m", "station.cli", "calibrate", str(folder), "--model", "geometric", "--out"]
        + [str(folder / "t.toml"), "--report", str(folder / "r.json")],
        cwd=ROOT, capture_output=True, timeout=300,
    )  # fmt: skip
    assert calibrate.returncode == 0, calibrate.stderr.decode(errors="replace")
    assert calibrate.stdout.splitlines()[-1] == b"wrote " + os.fsencode(f"{folder}/t.toml, {folder}/r.json")
    assert (
        "sitzung-\\xe4/samples.csv"
        in tomllib.loads((folder / "t.toml").read_text())["calibration"]["samples"]
    )
