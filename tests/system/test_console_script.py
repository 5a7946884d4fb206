"""The installed console script as a user runs it: a bad input is one line and exit 2, and the
command line answers without importing what only some commands need."""

import json
import re
import subprocess
import sys

import pytest

HEAVY = ("numpy", "scipy.stats", "rerun", "matplotlib", "pymodbus", "sim_fixtures", "drivers")
"""Imported only where used: together they take over a second to import (issue 15), the drivers
some milliseconds of every command (issue 36)."""


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


@pytest.mark.parametrize(
    "argv",
    [
        ["calibrate", "x.csv", "--robot", "r.toml", "--out", "o.toml"],
        ["--help"],
        ["--version"],
        ["sample", "--help"],
    ],
)
def test_parsing_any_command_line_imports_nothing_heavy(argv):
    # a fresh interpreter: the station's modules, the parser of every command, a parsed command line
    # (--help and --version answer while parsing: their output goes to stderr here, and they exit)
    code = (
        "import contextlib, json, sys; import station.cli as c\n"
        "with contextlib.redirect_stdout(sys.stderr), contextlib.suppress(SystemExit):\n"
        f"    c.build_parser().parse_args({argv!r})\n"
        f"print(json.dumps([m for m in {HEAVY!r} if m in sys.modules]))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert json.loads(proc.stdout) == []
    assert ("usage: station" in proc.stderr) is ("--help" in argv)


def test_version_through_the_console_script():
    proc = subprocess.run(
        [sys.executable, "-m", "station.cli", "--version"], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0 and proc.stderr == ""
    assert re.fullmatch(r"station \d+\.\d+\.\d+\S*\n", proc.stdout)


def test_calibrate_with_the_default_model_imports_no_scipy(three_lines, tmp_path):
    # issue 26: scipy.linalg alone costs about 0.2 s of import, scipy.cluster and scipy.special more;
    # the default calibration (k-means folds, LM steps, chi-square tails) needs none of them
    code = (
        "import json, sys; from station.cli import main\n"
        f"code = main(['calibrate', {str(three_lines.samples)!r}, '--robot', {str(three_lines.robot)!r}, "
        f"'--setup', {str(three_lines.setup)!r}, '--out', {str(tmp_path / 'c.toml')!r}, '--no-history'])\n"
        "print(json.dumps([code, sorted({m.split('.')[0] for m in sys.modules if m.startswith('scipy')})]))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.splitlines()[-1]) == [0, []]


@pytest.mark.parametrize(
    "argv",
    [["sim", "serve", "--seed", "-1"], ["demo", "--seed", "-3"], ["plan", "--out", "p.csv", "--seed", "-1"]],
)
def test_a_negative_seed_is_one_line_and_exit_2(argv, tmp_path):
    """numpy's generators take no negative seed: it was a ValueError traceback from deep inside."""
    proc = subprocess.run(
        [sys.executable, "-m", "station.cli", *argv], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.endswith(f"argument --seed: {argv[-1]} must be from 0 to 2**63 - 1"), proc.stderr


def test_a_reader_that_goes_away_ends_the_command_quietly(tmp_path):
    """``station history --json | head``: the pipe's reader gone before the command writes (here at
    once) was a BrokenPipeError traceback; now nothing on stderr and exit 1 (the output was not
    delivered whole)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "station.cli", "history", "--json", "--db", str(tmp_path / "h.sqlite")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # no reader left: the command's first write fails with EPIPE
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 1
    assert stderr == ""


def test_a_demo_plan_too_small_is_said_in_the_demos_own_flags(tmp_path):
    """``station demo --plan-size 20``: the planning job's n_select and per_line reached the user."""
    proc = subprocess.run(
        [sys.executable, "-m", "station.cli", "demo", "--no-viewer", "--plan-size", "20", "--out", "d"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith("station: error: --plan-size 20: ")
    assert "or change --plan-size" in proc.stderr
    assert "n_select" not in proc.stderr and "per_line" not in proc.stderr
