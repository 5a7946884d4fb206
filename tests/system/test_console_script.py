"""The installed console script as a user runs it: a bad input is one line and exit 2, and the
command line answers without importing what only some commands need."""

import json
import subprocess
import sys

HEAVY = ("numpy", "scipy.stats", "rerun", "matplotlib", "pymodbus", "sim_fixtures")
"""Imported only where used: together they take over a second to import (issue 15)."""


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


def test_parsing_any_command_line_imports_nothing_heavy():
    # a fresh interpreter: the station's modules, the parser of every command, a parsed command line
    code = (
        "import json, sys; import station.cli as c; "
        "c.build_parser().parse_args(['calibrate', 'x.csv', '--robot', 'r.toml', '--out', 'o.toml']); "
        f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert json.loads(proc.stdout) == []
