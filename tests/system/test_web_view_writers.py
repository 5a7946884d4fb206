"""What a second client can and cannot do to a session's web view (issue 21 item 10).

Rerun's gRPC server, which the web viewer reads, takes log data from any client that reaches its
port: it has no read-only mode, token or password (rerun-sdk 0.41: ``--bind``,
``--server-memory-limit``, ``--cors-allow-origin`` only). So a second client CAN log into the
session's recording and every viewer replays it; it CANNOT change what the station saves
(``session.rrd`` is written by the station's own stream). The viewer here is ``rerun URL --save``,
which records what the server replays to a viewer.
"""

from __future__ import annotations

import random
import subprocess
import sys
import time
from pathlib import Path

from rerun.chunk import RrdReader

from station.view.live import LiveView, _rerun_binary

INJECTED = "done: accuracy reached; INJECTED BY ANOTHER CLIENT"
SECOND_CLIENT = """
import sys
import rerun as rr
rec = rr.RecordingStream("station", recording_id=sys.argv[2])
rec.connect_grpc(sys.argv[1])
rec.log("log", rr.TextLog(sys.argv[3]))
rec.flush()
rec.disconnect()
"""


def _log_texts(rrd: Path) -> str:
    return " ".join(str(c) for c in RrdReader(rrd).stream().to_chunks() if c.entity_path == "/log")


def _seen_by_a_viewer(url: str, into: Path, timeout_s: float = 30.0) -> str:
    """The /log texts a viewer connecting to ``url`` is served (waits until the station's line came)."""
    viewer = subprocess.Popen(
        [_rerun_binary(), url, "--save", str(into), "--port", "0"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            time.sleep(0.5)
            if into.exists() and "station says" in _log_texts(into):
                time.sleep(1.0)  # the rest of the replay
                break
    finally:
        viewer.terminate()
        viewer.wait(10)
    return _log_texts(into)


def test_a_second_client_writes_into_every_viewer_but_not_into_the_session_record(tmp_path):
    folder = tmp_path / "sess"
    folder.mkdir()
    view = LiveView(folder / "session.rrd", web=f"127.0.0.{random.randint(2, 250)}")
    try:
        assert view.web is not None, view.notes
        assert view.notes == [f"live view: {view.web.url}"]  # this machine's own address: no note
        view.message("station says: sampling")
        view.rec.flush()
        other = subprocess.run(
            [sys.executable, "-c", SECOND_CLIENT, view.web.sink_url, "session-sess", INJECTED],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert other.returncode == 0, other.stderr
        seen = _seen_by_a_viewer(view.web.sink_url, tmp_path / "seen.rrd")
    finally:
        view.close()
    assert "station says" in seen and INJECTED in seen  # every viewer shows the injected line
    saved = _log_texts(folder / "session.rrd")
    assert "station says" in saved and INJECTED not in saved  # the station's record is its own
