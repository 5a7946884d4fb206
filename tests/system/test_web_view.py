"""``station sample --web`` in a real browser: headless Chromium (Debian's ``chromium``) driven by
Playwright opens the printed address as it is and renders the live view of a running simulated
session on a software renderer; the screenshot must show the session's data.

The check on the picture: the views draw the gauge lines, the live error and the predicted
workspace error in several colours, so at least ``MIN_HUES`` hue bins (of 16) hold
``MIN_PIXELS`` saturated pixels each; Rerun's welcome page (what a wrong or unreachable address
shows) holds two (its blue selection and the orange "software rasterizer" note).
``STATION_LIVE_VIEW_PNG=docs/live-view.png`` also saves the screenshot there (the README's, the first hour's).
"""

from __future__ import annotations

import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import tomli_w

CHROMIUM = Path("/usr/bin/chromium")
ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
RENDER_S = 25.0  # the viewer takes ~20 s to load and draw on a software renderer
READY_S = 60.0  # then up to this long for the session to show live errors (a loaded machine)
SHOWN_SAMPLES = 45  # the running calibration is determined by ~31 samples: live errors after it
MIN_HUES, MIN_PIXELS = 4, 150


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _config(folder: Path) -> Path:
    raw = {
        "time_scale": 3.0,  # the session outlasts a slow browser start on a loaded machine (SIGINT ends it)
        "robot": {"kind": "rtde", "host": f"127.0.0.{random.randint(2, 250)}"},
        "drawstring": {"kind": "modbus_tcp", "port": _free_port()},
        "dial": {"port": str(folder / "dial")},
        "reconnect": {"attempts": 2, "initial_s": 0.05},
        "session": {"plan": str(folder / "plan.csv")},
        "sim": {
            "speed_deg_s": 120.0,
            "accel_deg_s2": 480.0,
            "dwell_s": 2.0,
            "targets_per_line": 30,  # outlasts the wait for SHOWN_SAMPLES
            "plan_csv": str(folder / "plan.csv"),
        },
    }
    path = folder / "station.toml"
    path.write_text(tomli_w.dumps(raw))
    return path


def _station(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "station.cli", *args], stdout=subprocess.PIPE, text=True, **kw
    )


def _screenshot(url: str, out: Path, ready=lambda: True) -> None:
    """The page at ``url`` once it had ``RENDER_S`` to draw and ``ready()`` holds (up to
    ``READY_S``)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        page = browser.new_page(viewport={"width": 1400, "height": 850})
        page.goto(url)
        time.sleep(RENDER_S)
        deadline = time.monotonic() + READY_S
        while not ready() and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(2.0)  # the viewer draws what arrived
        page.screenshot(path=str(out))
        browser.close()


def _lines_of(proc: subprocess.Popen) -> list[str]:
    """The lines ``proc`` prints, gathered by a thread as they come."""
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    return lines


def _sample_index(line: str) -> int:
    found = re.match(r"sample (\d+) ", line)
    return int(found.group(1)) if found else -1


def _hue_bins(png: Path) -> np.ndarray:
    from PIL import Image

    hsv = np.asarray(Image.open(png).convert("HSV")).reshape(-1, 3).astype(int)
    saturated = hsv[(hsv[:, 1] > 100) & (hsv[:, 2] > 80)]
    return np.bincount(saturated[:, 0] // 16, minlength=16)


@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (apt-get install chromium)")
def test_the_printed_address_shows_the_live_session_in_a_browser(tmp_path):
    pytest.importorskip("playwright.sync_api", reason="needs playwright (pip install -e '.[dev]')")
    config = _config(tmp_path)
    sim = _station("sim", "serve", "--config", str(config))
    sample = None
    try:
        for _ in range(3):  # one line per device once it serves
            assert sim.stdout.readline(), "sim serve ended early"
        sample = _station("sample", "--config", str(config), "--out", str(tmp_path / "sess"), "--web")
        first = sample.stdout.readline()
        found = re.fullmatch(r"live view: (http://127\.0\.0\.1:\d+/\?url=\S+)\n", first)
        assert found, first
        url = found.group(1)
        printed = _lines_of(sample)
        shown = lambda: max(map(_sample_index, printed), default=-1) >= SHOWN_SAMPLES  # noqa: E731
        _screenshot(url, tmp_path / "live-view.png", shown)
        assert sample.poll() is None, "the session ended before the screenshot: it shows no live view"
        sample.send_signal(signal.SIGINT)
        assert sample.wait(30) in (0, 130)
    finally:
        for proc in (sample, sim):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                proc.wait(10)
    bins = _hue_bins(tmp_path / "live-view.png")
    if os.environ.get("STATION_LIVE_VIEW_PNG"):
        shutil.copy(tmp_path / "live-view.png", os.environ["STATION_LIVE_VIEW_PNG"])
    assert np.sum(bins >= MIN_PIXELS) >= MIN_HUES, bins
    assert "url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A" in url  # the recording's gRPC address, encoded


def test_a_web_bind_on_another_address_serves_there(tmp_path):
    """127.0.0.2 is still this machine's own (loopback): served there, no warning about others."""
    from station.view.live import LiveView

    view = LiveView(tmp_path / "session.rrd", web="127.0.0.2")
    try:
        (url,) = view.notes
        assert re.fullmatch(
            r"live view: http://127\.0\.0\.2:\d+/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.2%3A\d+%2Fproxy", url
        )
        with socket.create_connection(("127.0.0.2", view.web.web_port), timeout=2):
            pass
        with pytest.raises(OSError), socket.create_connection(("127.0.0.1", view.web.web_port), timeout=2):
            pass
    finally:
        view.close()
    assert view.web.proc.poll() is not None  # the viewer ends with the session


def test_a_web_bind_beyond_this_machine_says_so(tmp_path):
    from station.view.live import WRITERS, LiveView

    view = LiveView(tmp_path / "session.rrd", web="0.0.0.0")
    try:
        url, note = view.notes
        assert url.startswith(f"live view: http://{socket.gethostname()}:")
        assert note.startswith("note: --web-bind 0.0.0.0 serves the live view to every machine that reaches")
        assert note.endswith(WRITERS)  # said plainly who else can write into the view
    finally:
        view.close()


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGKILL])
def test_a_session_ended_by_a_signal_leaves_no_viewer_behind(tmp_path, signum):
    """SIGTERM (a service manager, ``kill``) stops the session as Ctrl-C does; even SIGKILL, which
    the station cannot see, ends the viewer's child process: none keeps holding the ports."""
    config = _config(tmp_path)
    sim = _station("sim", "serve", "--config", str(config))
    sample = None
    try:
        for _ in range(3):
            assert sim.stdout.readline(), "sim serve ended early"
        sample = _station("sample", "--config", str(config), "--out", str(tmp_path / "sess"), "--web")
        port = int(re.match(r"live view: http://127\.0\.0\.1:(\d+)/", sample.stdout.readline()).group(1))
        assert _listening(port)
        sample.send_signal(signum)
        code = sample.wait(30)
        assert code == (130 if signum == signal.SIGTERM else -signal.SIGKILL)
        deadline = time.monotonic() + 10
        while _listening(port) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _listening(port), "the viewer outlived the station"
    finally:
        for proc in (sample, sim):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                proc.wait(10)
