"""A resumed session's recording hand-over killed at each of its steps (issue 20, item 4): the
kill is injected at a named call (``tests.system.inject``), then the session is resumed again.
Whatever step the kill cut, the earlier recording is never replaced by a shorter one: the
finished session's ``session.rrd`` holds every sample, and the log says what it continues."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from station.view.live import recorded_samples
from tests.system.test_session import N_TARGETS, ROOT, _lines, rows_of, simulated, write_config

KILLS = {  # where in the hand-over: (before/after, the call, what its arguments name)
    "moved aside": ("after", "os:replace", "session.previous.rrd"),
    "new recording opened": ("after", "rerun:RecordingStream.set_sinks", ""),
    "earlier recording loaded": ("after", "rerun:RecordingStream.log_file_from_path", ""),
    "earlier recording about to be deleted": ("before", "pathlib:Path.unlink", "session.previous.rrd"),
}


@pytest.mark.parametrize("step", KILLS)
def test_a_kill_at_any_step_of_the_recording_hand_over_loses_no_recorded_sample(step, tmp_path):
    config = write_config(tmp_path)
    folder = tmp_path / "sess"
    sample = [sys.executable, "-m", "station.cli", "sample"]
    with simulated(config):
        first = subprocess.Popen([*sample, "--config", str(config), "--out", str(folder)], cwd=ROOT)
        deadline = time.monotonic() + 60
        while len(_lines(folder)) < 4 and time.monotonic() < deadline:
            time.sleep(0.02)
        first.send_signal(signal.SIGTERM)  # stopped after the sample in flight, recording closed
        assert first.wait(60) == 130
        taken = len(rows_of(folder))
        assert 3 <= taken < N_TARGETS and recorded_samples(folder / "session.rrd") == taken

        when, call, match = KILLS[step]
        inject = [sys.executable, "-m", "tests.system.inject", "SIGKILL", when, call, match, "--"]
        killed = subprocess.run([*inject, "sample", "--resume", str(folder)], cwd=ROOT, capture_output=True)
        assert killed.returncode == -signal.SIGKILL, killed.stderr

        again = subprocess.run([*sample, "--resume", str(folder)], cwd=ROOT, capture_output=True, text=True)
    assert again.returncode == 0, again.stdout + again.stderr
    assert [int(r["sample"]) for r in rows_of(folder)] == list(range(N_TARGETS))
    assert recorded_samples(folder / "session.rrd") == N_TARGETS  # the earlier samples too
    assert not (folder / "session.previous.rrd").exists()
    said = next(line for line in again.stdout.splitlines() if line.startswith("recording: "))
    kept = N_TARGETS if step == "earlier recording about to be deleted" else taken
    if step == "moved aside":  # the move was whole: an ordinary resume
        assert said == f"recording: session.rrd continues the earlier one ({taken} samples)"
    else:
        assert said.startswith("recording: an earlier resume was cut short; of its two recordings the longer")
        assert f"is kept ({kept} samples; the other: " in said
