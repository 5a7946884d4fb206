"""The live view in Rerun: every Rerun call of the station lives here.

One explicit recording stream per session (never the global one), saved to ``session.rrd`` and,
when asked, streamed to a native viewer (``--viewer``) or to a web viewer served by a child
``rerun`` process (``--web``: :class:`WebViewer`). A resumed session loads its earlier recording
into the new one, so ``session.rrd`` holds the whole session.

Entities (timelines ``sample``, the capture index, and ``session_time``, seconds since the start):

- ``cell/anchor``, ``cell/lines/<id>`` (static): the drawstring's cable exit and the gauge lines
  (fitted to the plan's nominal TCPs);
- ``cell/base`` (static): the robot's base;
- ``cell/path`` (nominal TCPs of the samples so far), ``cell/sample`` (the current one: grey
  before the running calibration is judged, green within its limit, red when suspect),
  ``cell/cable`` (anchor -> TCP) and the nominal robot as it stands: ``cell/robot/links``,
  ``cell/robot/joints``, ``cell/robot/tool`` (the tool's approach onto the TCP);
- a sweep session's ``cell/sweep/now`` (where the tool slides on a pass, as the robot's packages
  come: grey), ``cell/sweep/<pass>/rows`` (the nominal TCPs of a stored pass's rows, green) and
  ``cell/sweep/<pass>/flagged`` (its flagged rows, red), each as its pass is stored, on ``sample``
  too (its rows' index: the timeline the layout shows);
- ``progress``: samples taken of the plan's (a sweep: passes stored, the last one's rows and flagged
  rows);
- ``live/error`` (reading - the running calibration's prediction, made before the sample joins a
  fit), ``live/error/limit/upper|lower`` (what the prediction's uncertainty and the noise explain)
  and ``live/error/suspect`` (readings beyond it); ``live/predicted_workspace_mm`` and
  ``live/predicted_workspace_95_mm`` after each refit; ``live/length/reading|model`` and
  ``live/dial``; ``log`` (messages);
- after a calibration: ``calibration/residual/<method>/before|after`` per sample and
  ``calibration/cost/<method>`` per solver iteration (timeline ``iteration``).

The layout (blueprint) is declared once in :func:`blueprint`: the cell on the left, seen from an
eye that frames it (:func:`framing`); on the right the progress, the live error over its last
``RECENT_SAMPLES`` samples (at their own scale), the predicted workspace error; the log across the
bottom. The log's last line names the recording to replay once the view is gone.
"""

from __future__ import annotations

import ipaddress
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path
from urllib.parse import quote

import numpy as np

# Rerun logs a failing file sink (a full disk) on stderr itself, several lines, besides the error
# that reaches us at flush: keep the station's one line (other warnings stay).
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding=off,re_sdk::recording_stream=off")
import rerun as rr  # noqa: E402
import rerun.blueprint as rrb  # noqa: E402
from rerun.chunk import RrdReader  # noqa: E402

from station.formats.base import printable  # noqa: E402

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


LOG_WIDTH = 150
"""Characters per session-log row: the log spans the window, about 190 characters at 1400 px."""
RECENT_SAMPLES = 20
"""The live error's plot shows this many recent samples, at their own scale: the first samples of a
line, millimetres off, would flatten the hundredths that follow."""
ROBOT, TOOL = (40, 120, 140), (240, 150, 30)
SWEEP_RADII = {"now": -2.0, "rows": -1.5, "flagged": -2.5}
"""A sweep's points in UI points (negative: Rerun's screen size), not millimetres: rows a
millimetre apart along metre-long lines would be below a pixel in the whole cell's view."""


def blueprint(eye: rrb.EyeControls3D | None = None) -> rrb.Blueprint:
    """The layout: the cell (seen from ``eye``) left, the live plots right, the log across the
    bottom (its rows whole)."""
    recent = rrb.VisibleTimeRange(
        "sample",
        start=rrb.TimeRangeBoundary.cursor_relative(seq=-RECENT_SAMPLES),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    live = rrb.Vertical(
        rrb.TextDocumentView(name="progress", origin="/progress"),
        rrb.TimeSeriesView(
            name=f"live error, last {RECENT_SAMPLES} samples: reading - running calibration (mm)",
            origin="/live/error",
            time_ranges=[recent],
        ),
        rrb.TimeSeriesView(
            name="predicted workspace error (mm)",
            origin="/live",
            contents=["$origin/predicted_workspace_mm", "$origin/predicted_workspace_95_mm"],
        ),
        row_shares=[1, 4, 3],
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
    log = rrb.TextLogView(
        name="session log",
        origin="/log",
        columns=rrb.TextLogColumns(
            text_log_columns=[
                rrb.components.TextLogColumn("EntityPath", visible=False),
                rrb.components.TextLogColumn("LogLevel"),
                rrb.components.TextLogColumn("Body"),
            ]
        ),
    )
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial3DView(name="cell (base frame, mm)", origin="/cell", eye_controls=eye),
                rrb.Tabs(live, readings, calibration),
                column_shares=[2, 3],
            ),
            log,
            row_shares=[3, 1],
        ),
        rrb.TimePanel(timeline="sample", state="collapsed"),
        collapse_panels=True,
    )


def framing(points_mm: np.ndarray) -> rrb.EyeControls3D:
    """An eye that frames ``points_mm`` (N, 3) (the robot's base, the anchor, the gauge lines):
    from the front-left and above their centre, far enough to see them all, z up."""
    points = np.vstack([np.zeros(3), np.asarray(points_mm, float)])
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, size = (lo + hi) / 2, float(np.linalg.norm(hi - lo))
    away = np.array([-0.55, -0.7, 0.45])
    away /= np.linalg.norm(away)
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=(centre + 1.0 * size * away).tolist(),
        look_target=centre.tolist(),
        eye_up=[0.0, 0.0, 1.0],
    )


class LiveView:
    """A session's Rerun recording, saved to ``rrd``; ``viewer`` also streams it to a native
    viewer and ``web`` (a bind address) to a served web viewer; ``resume`` loads the recording
    already at ``rrd`` first."""

    def __init__(self, rrd: Path, *, viewer: bool = False, web: str | None = None, resume: bool = False):
        rrd = Path(rrd)
        self.rrd = rrd
        # the id is text Rerun sends as UTF-8: a folder name that is not is shown with \xNN
        self.rec = rr.RecordingStream("station", recording_id=f"session-{printable(rrd.parent.name)}")
        self.notes: list[str] = []
        self.incomplete: str | None = None
        self.web: WebViewer | None = None
        self._previous = rrd.with_name(rrd.stem + ".previous.rrd")  # loaders go by extension
        if resume:  # the new sink truncates rrd: keep what it held
            self.notes.append(hand_over(rrd, self._previous))
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
            if not _loopback(web):
                self.notes.append(
                    f"note: --web-bind {web} serves the live view to every machine that reaches this one "
                    f"on ports {self.web.web_port} and {self.web.grpc_port}: {WRITERS}"
                )
        return sinks

    def cell(self, anchor_mm, lines: dict[int, np.ndarray], robot_mm=None) -> None:
        """Static scene: the anchor and each gauge line as a segment (2, 3) in mm, the robot's base,
        the view framed on them and on ``robot_mm`` (K, 3), where the robot's joints will go;
        series styles."""
        self._anchor = np.asarray(anchor_mm, float)
        scene = [self._anchor[None], *lines.values()]
        scene += [] if robot_mm is None else [np.asarray(robot_mm, float).reshape(-1, 3)]
        self.rec.send_blueprint(blueprint(framing(np.vstack(scene))))
        self.rec.log(
            "cell/base",
            rr.Points3D([[0.0, 0.0, 0.0]], radii=25.0, colors=[ROBOT], labels=["robot base"]),
            static=True,
        )
        self.rec.log(
            "cell/anchor",
            rr.Points3D([self._anchor], radii=8.0, colors=[GREY], labels=["drawstring anchor"]),
            static=True,
        )
        for lid, seg in lines.items():
            self.rec.log(
                f"cell/lines/{lid}", rr.LineStrips3D([seg], radii=4.0, labels=[f"line {lid}"]), static=True
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

    def sample(
        self,
        index: int,
        t_s: float,
        tcp_mm,
        length_mm: float,
        dial_mm: float,
        live,
        chain_mm=None,
        approach=None,
    ) -> None:
        """One stored sample: where the nominal model puts the TCP, and ``live`` (``model_mm``,
        ``error_mm``, ``limit_mm``, ``suspect``; None until the running calibration is judged)
        against the running calibration; ``chain_mm`` (K, 3), the robot drawn through its joints to
        the TCP, and the tool's ``approach`` (unit, base frame) where given."""
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
        if chain_mm is not None:
            self._robot(np.asarray(chain_mm, float), tcp, approach)
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

    def sweeping(self, tcp_mm, t_s: float, sample: int) -> None:
        """Where the tool slid on a pass since the last call: nominal TCPs (N, 3) [mm], at session
        time ``t_s`` [s] and ``sample``, the index the pass's first row will take (the view's
        timeline is the rows' index in both kinds of session)."""
        self.rec.set_time("sample", sequence=sample)
        self.rec.set_time("session_time", duration=t_s)
        self.rec.log(
            "cell/sweep/now",
            rr.Points3D(np.asarray(tcp_mm, float).reshape(-1, 3), radii=SWEEP_RADII["now"], colors=[GREY]),
        )

    def sweep(self, pass_id: int, line: int, tcp_mm, flagged_mm, t_s: float, *, sample: int, passes) -> None:
        """A sweep's stored pass on gauge ``line``: the nominal TCPs (N, 3) [mm] of its rows and
        (K, 3) of its flagged rows, at session time ``t_s`` [s] and ``sample`` (its last row's
        index); ``passes`` (done, total) for the progress."""
        self.rec.set_time("sample", sequence=sample)
        self.rec.set_time("session_time", duration=t_s)
        tcp, flagged = (np.asarray(v, float).reshape(-1, 3) for v in (tcp_mm, flagged_mm))
        self.rec.log(
            f"cell/sweep/{pass_id}/rows", rr.Points3D(tcp, radii=SWEEP_RADII["rows"], colors=[GREEN])
        )
        if len(flagged):
            self.rec.log(
                f"cell/sweep/{pass_id}/flagged",
                rr.Points3D(flagged, radii=SWEEP_RADII["flagged"], colors=[RED]),
            )
        done, total = passes
        self.rec.log(
            "progress",
            rr.TextDocument(
                f"**{done} of {total} passes** ({100.0 * done / max(total, 1):.0f} %), the last on line "
                f"{line}: {len(tcp)} rows stored (green), {len(flagged)} flagged (red)",
                media_type=rr.MediaType.MARKDOWN,
            ),
        )

    def _robot(self, chain: np.ndarray, tcp: np.ndarray, approach) -> None:
        """The robot as it stands: links through its joints, the joints, and the tool pointing
        along ``approach`` onto the TCP."""
        self.rec.log("cell/robot/links", rr.LineStrips3D([chain], radii=12.0, colors=[ROBOT]))
        self.rec.log("cell/robot/joints", rr.Points3D(chain[:-1], radii=18.0, colors=[ROBOT]))
        if approach is not None:
            tool = 150.0 * np.asarray(approach, float)
            self.rec.log(
                "cell/robot/tool",
                rr.Arrows3D(origins=[tcp - tool], vectors=[tool], radii=6.0, colors=[TOOL]),
            )

    def progress(self, done: int, total: int, line: int) -> None:
        """How far the session is: ``done`` of ``total`` samples, the last on gauge ``line``."""
        share = 100.0 * done / max(total, 1)
        self.rec.log(
            "progress",
            rr.TextDocument(
                f"**{done} of {total} samples** ({share:.0f} %), the last on line {line}",
                media_type=rr.MediaType.MARKDOWN,
            ),
        )

    def refit(self, index: int, predicted_mm: float, bound_95_mm: float) -> None:
        """The running calibration's predicted workspace error [mm] and its 95 % bound after a refit
        on the samples up to ``index``."""
        self.rec.set_time("sample", sequence=index)
        self.rec.disable_timeline("session_time")  # a refit answers at no sample's time
        self.rec.log("live/predicted_workspace_mm", rr.Scalars(predicted_mm))
        self.rec.log("live/predicted_workspace_95_mm", rr.Scalars(bound_95_mm))

    def message(self, text: str) -> None:
        """A session-log line; a long one in rows of ``LOG_WIDTH`` characters (the view cuts a row
        at its right edge), the rows after the first indented."""
        level = log_level(text)
        for row in textwrap.wrap(text, LOG_WIDTH, subsequent_indent="    ") or [""]:
            self.rec.log("log", rr.TextLog(row, level=level))

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
        what it has; ``incomplete`` says why (None: complete). The log's last line says where to
        see it again once this view is gone."""
        self.message(f"session over; replay it with: rerun {self.rrd}")
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


def hand_over(rrd: Path, previous: Path) -> str:
    """Move a resumed session's recording ``rrd`` aside to ``previous``, which the new recording
    loads first and :meth:`LiveView.close` deletes once it holds it all; what it holds, said. A
    kill can cut this short at any step, leaving both: then the one holding more samples is kept,
    so the earlier recording is never replaced by a shorter one."""
    if rrd.exists() and previous.exists():
        new, old = recorded_samples(rrd), recorded_samples(previous)
        if (new or 0) > (old or 0):
            os.replace(rrd, previous)
            new, old = old, new
        else:
            rrd.unlink()
        return (
            f"recording: an earlier resume was cut short; of its two recordings the longer is kept "
            f"({old or 0} samples; the other: {'unreadable' if new is None else f'{new} samples'})"
        )
    if rrd.exists():
        os.replace(rrd, previous)
    if not previous.exists():
        return f"recording: no earlier recording in {rrd.parent}; {rrd.name} holds the samples from here on"
    held = recorded_samples(previous)
    if held is None:
        return "recording: the earlier one was cut short by a crash; what of it can be read is loaded"
    return f"recording: {rrd.name} continues the earlier one ({held} samples)"


def recorded_samples(rrd: Path) -> int | None:
    """The samples a recording holds (rows of ``live/length/reading``); None if it cannot be read
    (cut short by a crash: Rerun reads a file whole or not at all)."""
    try:
        with warnings.catch_warnings():  # a recording cut short has no footer: Rerun warns
            warnings.simplefilter("ignore")
            chunks = list(RrdReader(rrd).stream())
    except (RuntimeError, OSError):
        return None
    return sum(c.num_rows for c in chunks if c.entity_path == "/live/length/reading" and not c.is_static)


def _loopback(bind: str) -> bool:
    """Whether only this machine reaches ``bind`` (127.0.0.0/8, ::1, localhost)."""
    try:
        return bind == "localhost" or ipaddress.ip_address(bind).is_loopback
    except ValueError:  # a host name: whatever it resolves to may be reached from elsewhere
        return False


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
