"""The installed console script as a user runs it: a bad input is one line and exit 2."""

import subprocess
import sys


def test_console_script_runs_without_traceback(three_lines, tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "station.cli",
            "calibrate",
            str(tmp_path / "nope.csv"),
            "--robot",
            str(three_lines.robot),
            "--out",
            str(tmp_path / "c.toml"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "Traceback" not in proc.stderr
    assert "nope.csv" in proc.stderr and "no such file" in proc.stderr
