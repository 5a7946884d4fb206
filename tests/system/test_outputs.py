"""A command's outputs are written all or none: a write that fails after the work (here a disk that
fills, emulated by a file-size limit in the child: the table and report fit under it, the PNG does
not) ends in one line and exit 2, with none of the outputs left and no temporary file behind."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

import configs
from sim_fixtures.scenario import write_scenario
from tests.system.test_full_disk import limit_file_size
from tests.system.test_session import ROOT

LIMIT = 40_000  # bytes: a corrected table (20 kB), a report, a plan; not a PNG (55-85 kB)
ROBOT, SETUP = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    return write_scenario(tmp_path_factory.mktemp("cell"), seed=3, n_lines=3, n_per_line=30)


def _commands(cell, out):
    inputs = [str(cell.samples), "--robot", str(cell.robot), "--setup", str(cell.setup)]
    return {
        "calibrate": [
            ["calibrate", *inputs, "--model", "geometric"],
            ["--out", str(out / "t.toml"), "--report", str(out / "r.json"), "--plot", str(out / "p.png")],
        ],
        "plan": [
            ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--no-suggest", "--per-line", "30"],
            ["--out", str(out / "plan.csv"), "--report", str(out / "r.json"), "--plot", str(out / "p.png")],
        ],
        "compare": [
            ["compare", *inputs, "--methods", "gn,lmlc"],
            ["--report", str(out / "r.json"), "--plot", str(out / "p.png")],
        ],
    }


@pytest.mark.parametrize("command", ["calibrate", "plan", "compare"])
def test_a_write_failing_after_the_work_leaves_no_output(command, cell, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    head, outputs = _commands(cell, out)[command]
    cmd = [sys.executable, "-m", "station.cli", *head, *outputs]
    proc = subprocess.run(
        cmd, cwd=ROOT, preexec_fn=lambda: limit_file_size(LIMIT), capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 2, proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if not ln.startswith("... ")]  # progress lines
    (error,) = errors
    assert error.startswith(f"station: error: --plot {out / 'p.png'}: cannot write (File too large)")
    assert error.endswith("nothing written (" + ", ".join(outputs[1::2]) + ")")
    assert list(out.iterdir()) == []
    assert subprocess.run(cmd, cwd=ROOT, capture_output=True, timeout=300).returncode == 0  # room again
    assert sorted(p.name for p in out.iterdir()) == sorted(p.rsplit("/", 1)[1] for p in outputs[1::2])


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_stop_signal_between_the_renames_leaves_every_output_or_none(sig, cell, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    head, outputs = _commands(cell, out)["calibrate"]
    # the signal arrives right after the table is renamed into place, before the report and plot
    inject = [sys.executable, "-m", "tests.system.inject", sig, "after", "os:replace", "t.toml", "--"]
    # as a terminal's foreground command gets it: a runner that starts the tests in the background
    # hands on SIGINT ignored, and a command started so ignores Ctrl-C (Python installs no handler)
    proc = subprocess.run(
        [*inject, *head, *outputs],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.splitlines()[-1] == "station: interrupted"
    assert sorted(p.name for p in out.iterdir()) == ["p.png", "r.json", "t.toml"]  # all, no temporary
