"""The live view in Rerun: every Rerun call of the station lives here.

One explicit recording stream per session (never the global one), saved to ``session.rrd`` and,
when asked, streamed to a native viewer (``--viewer``) or to a web viewer served by a child
``rerun`` process (``--web``: :class:`WebViewer`). A resumed session loads its earlier recording
into the new one, so ``session.rrd`` holds the whole session.

Entities (timelines ``sample``, the capture index, and ``session_time``, seconds since the start):

- ``cell/anchor``, ``cell/lines/<id>`` (static): the drawstring's cable exit and the gauge lines
  (fitted to the plan's nominal TCPs);
- ``cell/path`` (nominal TCPs of the samples so far), ``cell/sample`` (the current one: grey
  before the running calibration is judged, green within its limit, red when suspect) and
  ``cell/cable`` (anchor -> TCP);
- ``live/error`` (reading - the running calibration's prediction, made before the sample joins a
  fit), ``live/error/limit/upper|lower`` (what the prediction's uncertainty and the noise explain)
  and ``live/error/suspect`` (readings beyond it); ``live/predicted_workspace_mm`` and
  ``live/predicted_workspace_95_mm`` after each refit; ``live/length/reading|model`` and
  ``live/dial``; ``log`` (messages);
- after a calibration: ``calibration/residual/<method>/before|after`` per sample and
  ``calibration/cost/<method>`` per solver iteration (timeline ``iteration``).

The layout (blueprint) is declared once in :func:`blueprint`: the cell on the left; on the right
the live error largest, the predicted workspace error under it, then the log.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import quote

import numpy as np

# Rerun logs a failing file sink (a full disk) on stderr itself, several lines, besides the error
# that reaches us at flush: keep the station's one line (other warnings stay).
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding=off,re_sdk::recording_stream=off")
import rerun as rr  # noqa: E402
import rerun.blueprint as rrb  # noqa: E402

GREEN, RED, GREY = (40, 200, 80), (230, 60, 50), (150, 150, 150)
FLUSH_TIMEOUT_S = 10.0
BLUE, ORANGE, PURPLE = (60, 120, 230), (240, 150, 30), (170, 80, 200)
LOOPBACK = ("127.0.0.1", "localhost", "::1")
WRITERS = (
    "anyone there can watch it and can also log into it, e.g. a false 'done' line (Rerun's gRPC server "
    "takes data from every client: it has no read-only mode and no password); session.rrd keeps only "
    "what the station logged"
)
"""What others who reach the web view's gRPC port can do (README, "Live view security")."""
WARN_WORDS = ("suspended", "rejected", "retrying", "failed", "timed out", "check the cable")


def blueprint() -> rrb.Blueprint:
    live = rrb.Vertical(
        rrb.TimeSeriesView(name="live error: reading - running calibration (mm)", origin="/live/error"),
        rrb.TimeSeriesView(
            name="predicted workspace error (mm)",
            origin="/live",
            contents=["$origin/predicted_workspace_mm", "$origin/predicted_workspace_95_mm"],
        ),
        rrb.TextLogView(name="session log", origin="/log"),
        row_shares=[3, 2, 2],
        name="live",
    )
    readings = rrb.Vertical(
        rrb.TimeSeriesView(name="drawstring: reading and model (mm)", origin="/live/length"),
        rrb.TimeSeriesView(name="dial (mm)", origin="/live/dial"),
        name="readings",
    )
    calibration = rrb.Vertical(
        rrb.TimeSeriesView(name="residual per sample (mm)", origin="/calibration/residual"),
        rrb.TimeSeriesView(name="solver cost per iteration", origin="/calibration/cost"),
        name="calibration",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="cell (base frame, mm)", origin="/cell"),
            rrb.Tabs(live, readings, calibration),
            column_shares=[2, 3],
        ),
        rrb.TimePanel(timeline="sample", state="collapsed"),
        collapse_panels=True,
    )


class LiveView:
    """A session's Rerun recording, saved to ``rrd``; ``viewer`` also streams it to a native
    viewer and ``web`` (a bind address) to a served web viewer; ``resume`` loads the recording
    already at ``rrd`` first."""

    def __init__(self, rrd: Path, *, viewer: bool = False, web: str | None = None, resume: bool = False):
        rrd = Path(rrd)
        self.rec = rr.RecordingStream("station", recording_id=f"session-{rrd.parent.name}")
        self.notes: list[str] = []
        self.incomplete: str | None = None
        self.web: WebViewer | None = None
        self._previous = rrd.with_name(rrd.stem + ".previous.rrd")  # loaders go by extension
        if resume and rrd.exists():
            os.replace(rrd, self._previous)  # the new sink truncates rrd: keep what it held
        sinks = [rr.FileSink(str(rrd)), *self._live_sinks(viewer, web)]
        try:
            self.rec.set_sinks(*sinks)
            self.rec.send_blueprint(blueprint())
            if self._previous.exists():
                self.rec.log_file_from_path(self._previous)
        except BaseException:  # no view for the caller to close: stop the viewer here
            if self.web is not None:
                self.web.close()
            raise
        self._path: list[np.ndarray] = []
        self._anchor = np.zeros(3)

    def _live_sinks(self, viewer: bool, web: str | None) -> list:
        sinks = []
        if viewer and not _has_display():
            self.notes.append("no display: viewer not opened (open the .rrd later with `rerun FILE`)")
        elif viewer:
            try:
                rr.spawn(connect=False, hide_welcome_screen=True)
                sinks.append(rr.GrpcSink())
            except (OSError, RuntimeError) as exc:
                self.notes.append(f"viewer not opened: {exc}")
        if web is not None:
            try:
                self.web = WebViewer(web)
            except (OSError, RuntimeError) as exc:  # the session goes on; session.rrd has it all
                self.notes.append(f"web viewer not started: {exc}")
                return sinks
            sinks.append(rr.GrpcSink(self.web.sink_url))
            self.notes.append(f"live view: {self.web.url}")
            if web not in LOOPBACK:
                self.notes.append(
                    f"note: --web-bind {web} serves the live view to every machine that reaches this one "
                    f"on ports {self.web.web_port} and {self.web.grpc_port}: {WRITERS}"
                )
        return sinks

    def cell(self, anchor_mm, lines: dict[int, np.ndarray]) -> None:
        """Static scene: the anchor and each gauge line as a segment (2, 3) in mm; series styles."""
        self._anchor = np.asarray(anchor_mm, float)
        self.rec.log(
            "cell/anchor",
            rr.Points3D([self._anchor], radii=8.0, colors=[GREY], labels=["drawstring anchor"]),
            static=True,
        )
        for lid, seg in lines.items():
            self.rec.log(
                f"cell/lines/{lid}", rr.LineStrips3D([seg], radii=2.0, labels=[f"line {lid}"]), static=True
            )
        styles = {
            "live/length/reading": rr.SeriesLines(names="reading", colors=[BLUE]),
            "live/length/model": rr.SeriesLines(names="model", colors=[GREY]),
            "live/error": rr.SeriesLines(names="live error", colors=[BLUE], widths=2.0),
            "live/error/limit/upper": rr.SeriesLines(names="limit", colors=[GREY]),
            "live/error/limit/lower": rr.SeriesLines(names="limit", colors=[GREY]),
            "live/error/suspect": rr.SeriesPoints(names="suspect", colors=[RED], marker_sizes=6.0),
            "live/predicted_workspace_mm": rr.SeriesLines(names="expected", colors=[ORANGE], widths=2.0),
            "live/predicted_workspace_95_mm": rr.SeriesLines(names="95 % bound", colors=[PURPLE]),
        }
        for path, style in styles.items():
            self.rec.log(path, style, static=True)

    def sample(self, index: int, t_s: float, tcp_mm, length_mm: float, dial_mm: float, live) -> None:
        """One stored sample: where the nominal model puts the TCP, and ``live`` (``model_mm``,
        ``error_mm``, ``limit_mm``, ``suspect``; None until the running calibration is judged)
        against the running calibration."""
        self.rec.set_time("sample", sequence=index)
        self.rec.set_time("session_time", duration=t_s)
        tcp = np.asarray(tcp_mm, float)
        color = GREY if live.error_mm is None else RED if live.suspect else GREEN
        label = f"#{index}" if live.error_mm is None else f"#{index}: {live.error_mm:+.3f} mm"
        self._path.append(tcp)
        self.rec.log("cell/path", rr.LineStrips3D([np.array(self._path)], radii=0.8, colors=[GREY]))
        self.rec.log("cell/sample", rr.Points3D([tcp], radii=6.0, colors=[color], labels=[label]))
        self.rec.log(
            "cell/cable", rr.LineStrips3D([np.array([self._anchor, tcp])], radii=1.0, colors=[color])
        )
        self.rec.log("live/length/reading", rr.Scalars(length_mm))
        if np.isfinite(dial_mm):
            self.rec.log("live/dial", rr.Scalars(dial_mm))
        if live.error_mm is None:
            return
        self.rec.log("live/length/model", rr.Scalars(live.model_mm))
        self.rec.log("live/error", rr.Scalars(live.error_mm))
        self.rec.log("live/error/limit/upper", rr.Scalars(live.limit_mm))
        self.rec.log("live/error/limit/lower", rr.Scalars(-live.limit_mm))
        if live.suspect:
            self.rec.log("live/error/suspect", rr.Scalars(live.error_mm))

    def refit(self, index: int, predicted_mm: float, bound_95_mm: float) -> None:
        """The running calibration's predicted workspace error [mm] and its 95 % bound after a refit
        on the samples up to ``index``."""
        self.rec.set_time("sample", sequence=index)
        self.rec.disable_timeline("session_time")  # a refit answers at no sample's time
        self.rec.log("live/predicted_workspace_mm", rr.Scalars(predicted_mm))
        self.rec.log("live/predicted_workspace_95_mm", rr.Scalars(bound_95_mm))

    def message(self, text: str) -> None:
        self.rec.log("log", rr.TextLog(text, level=log_level(text)))

    def calibration(self, method: str, before_mm, after_mm, cost_per_iteration) -> None:
        """Per-sample drawstring residuals (mm) before and after, and the solver's cost history."""
        self.rec.reset_time()
        base = f"calibration/residual/{method}"
        self.rec.log(f"{base}/before", rr.SeriesPoints(names=f"{method} before", colors=[RED]), static=True)
        self.rec.log(f"{base}/after", rr.SeriesPoints(names=f"{method} after", colors=[GREEN]), static=True)
        for i, (b, a) in enumerate(zip(before_mm, after_mm, strict=True)):
            self.rec.set_time("sample", sequence=i)
            self.rec.log(f"{base}/before", rr.Scalars(float(b)))
            self.rec.log(f"{base}/after", rr.Scalars(float(a)))
        for k, cost in enumerate(cost_per_iteration):
            self.rec.set_time("iteration", sequence=k)
            self.rec.log(f"calibration/cost/{method}", rr.Scalars(float(cost)))

    def close(self) -> None:
        """Flush and close the recording. One that could not be written whole (disk full) keeps
        what it has; ``incomplete`` says why (None: complete)."""
        try:
            self.rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as exc:
            self.incomplete = str(exc)
        finally:
            self.rec.disconnect()
        if self.incomplete is None:
            self._previous.unlink(missing_ok=True)  # now inside the new recording
        if self.web is not None:
            self.web.close()


class WebViewer:
    """Rerun's web viewer and the gRPC server it reads, served by a child ``rerun`` process bound
    to ``bind`` (default ports 9090 and 9876, free ones when taken). ``url`` is the page a browser
    opens as it is: the viewer with the recording's gRPC address in its query."""

    START_S = 15.0

    def __init__(self, bind: str):
        self.web_port, self.grpc_port = _port(bind, 9090), _port(bind, 9876)
        host = socket.gethostname() if bind in ("0.0.0.0", "::") else bind
        self.sink_url = f"rerun+http://{_connectable(bind)}:{self.grpc_port}/proxy"
        grpc_url = f"rerun+http://{_url_host(host)}:{self.grpc_port}/proxy"
        self.url = f"http://{_url_host(host)}:{self.web_port}/?url={quote(grpc_url, safe='')}"
        cmd = [_rerun_binary(), "--serve-web", "--bind", bind, "--port", str(self.grpc_port)]
        cmd += ["--web-viewer-port", str(self.web_port)]
        if bind not in LOOPBACK:  # the page's origin is not localhost: let it read the gRPC server
            cmd += ["--cors-allow-origin", f"http://{_url_host(host)}:{self.web_port}"]
        # its own session: a Ctrl-C for the station must not end the view before the last row
        self.proc = subprocess.Popen(
            cmd,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
            preexec_fn=_death_signal() if sys.platform == "linux" else None,
        )
        self._wait_listening(_connectable(bind))

    def _wait_listening(self, host: str) -> None:
        deadline = time.monotonic() + self.START_S
        while time.monotonic() < deadline and self.proc.poll() is None:
            try:
                with socket.create_connection((host, self.web_port), timeout=0.5):
                    return
            except OSError:
                time.sleep(0.05)
        self.close()
        raise RuntimeError(f"the web viewer did not start on port {self.web_port}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def log_level(text: str) -> rr.TextLogLevel:
    """A session-log line's level: ``WARN`` where it reports a fault, a lost capture or a suspect
    reading (``WARN_WORDS``), else ``INFO``."""
    return rr.TextLogLevel.WARN if any(word in text for word in WARN_WORDS) else rr.TextLogLevel.INFO


def _death_signal():
    """What the viewer's child process runs before ``exec`` (Linux): SIGTERM it when the station
    dies, even by SIGKILL, so that no orphaned viewer keeps holding the ports. ``prctl`` is looked
    up here, in the parent: the child of a process with threads (the device readers) must only
    call it."""
    import ctypes

    prctl, pr_set_pdeathsig = ctypes.CDLL(None, use_errno=True).prctl, 1
    return lambda: prctl(pr_set_pdeathsig, signal.SIGTERM)


def _rerun_binary() -> str:
    """The viewer binary the Rerun SDK ships (``rerun_cli``), run directly so it can be stopped."""
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / ("rerun.exe" if sys.platform == "win32" else "rerun"))


def _port(bind: str, preferred: int) -> int:
    """``preferred`` if free on ``bind``, else one the system picks."""
    family = socket.AF_INET6 if ":" in bind else socket.AF_INET
    for port in (preferred, 0):
        with socket.socket(family) as s:
            try:
                s.bind((bind, port))
            except OSError:
                continue
            return s.getsockname()[1]
    raise OSError(f"no free port on {bind}")


def _connectable(bind: str) -> str:
    """Where this process reaches a server bound to ``bind``."""
    return {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(bind, bind)


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def _has_display() -> bool:
    return sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
