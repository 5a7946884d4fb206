"""The live error view in Rerun: every Rerun call of the station lives here.

One explicit recording stream per session (never the global one), saved to ``session.rrd`` and,
when asked, streamed to a native viewer (``--viewer``) or a served web viewer (``--web``).

Entities (timelines ``sample``, the capture index, and ``session_time``, seconds since the start):

- ``cell/anchor``, ``cell/lines/<id>`` (static): the drawstring's cable exit and the gauge lines
  (fitted to the plan's nominal TCPs);
- ``cell/path`` (nominal TCPs of the samples so far), ``cell/sample`` (the current one, green
  when its live error is within ``ok_mm``, red otherwise) and ``cell/cable`` (anchor -> TCP);
- ``live/length/reading`` and ``live/length/model`` (drawstring reading and the length the
  current model predicts), ``live/error`` (their difference), ``live/dial``; ``log`` (messages);
- after a calibration: ``calibration/residual/<method>/before|after`` per sample and
  ``calibration/cost/<method>`` per solver iteration (timeline ``iteration``).

The layout (blueprint) is declared once in :func:`blueprint`: the cell on the left, the live
error largest on the right, so an operator sees at a glance whether the current sample is good.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

# Rerun logs a failing file sink (a full disk) on stderr itself, several lines, besides the error
# that reaches us at flush: keep the station's one line (other warnings stay).
os.environ.setdefault("RUST_LOG", "warn,re_log_encoding=off,re_sdk::recording_stream=off")
import rerun as rr  # noqa: E402
import rerun.blueprint as rrb  # noqa: E402

GREEN, RED, GREY = (40, 200, 80), (230, 60, 50), (150, 150, 150)
FLUSH_TIMEOUT_S = 10.0


def blueprint() -> rrb.Blueprint:
    live = rrb.Vertical(
        rrb.TimeSeriesView(name="live error: reading - model (mm)", origin="/live/error"),
        rrb.TimeSeriesView(name="drawstring: reading and model (mm)", origin="/live/length"),
        rrb.TimeSeriesView(name="dial (mm)", origin="/live/dial"),
        rrb.TextLogView(name="session log", origin="/log"),
        row_shares=[3, 2, 2, 2],
        name="live",
    )
    calibration = rrb.Vertical(
        rrb.TimeSeriesView(name="residual per sample (mm)", origin="/calibration/residual"),
        rrb.TimeSeriesView(name="solver cost per iteration", origin="/calibration/cost"),
        name="calibration",
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="cell (base frame, mm)", origin="/cell"),
            rrb.Tabs(live, calibration),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


class LiveView:
    """A session's Rerun recording, saved to ``rrd``; ``viewer``/``web`` also stream it live."""

    def __init__(self, rrd: Path, *, viewer: bool = False, web: bool = False, ok_mm: float = 1.0):
        self.rec = rr.RecordingStream("station", recording_id=f"session-{Path(rrd).parent.name}")
        self.ok_mm = ok_mm
        self.notes: list[str] = []
        self.incomplete: str | None = None
        sinks = [rr.FileSink(str(rrd)), *self._live_sinks(viewer, web)]
        self.rec.set_sinks(*sinks)
        self.rec.send_blueprint(blueprint())
        self._path: list[np.ndarray] = []
        self._anchor = np.zeros(3)

    def _live_sinks(self, viewer: bool, web: bool) -> list:
        sinks = []
        if viewer and not _has_display():
            self.notes.append("no display: viewer not opened (open the .rrd later with `rerun FILE`)")
        elif viewer:
            try:
                rr.spawn(connect=False, hide_welcome_screen=True)
                sinks.append(rr.GrpcSink())
            except (OSError, RuntimeError) as exc:
                self.notes.append(f"viewer not opened: {exc}")
        if web:
            server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=9876)
            sinks.append(server)
            rr.serve_web_viewer(connect_to=server.uri, open_browser=_has_display())
            self.notes.append(f"web viewer serving {server.uri}")
        return sinks

    def cell(self, anchor_mm, lines: dict[int, np.ndarray]) -> None:
        """Static scene: the anchor and each gauge line as a segment (2, 3) in mm."""
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
        self.rec.log(
            "live/length/reading", rr.SeriesLines(names="reading", colors=[[60, 120, 230]]), static=True
        )
        self.rec.log("live/length/model", rr.SeriesLines(names="model", colors=[GREY]), static=True)

    def sample(
        self, index: int, t_s: float, tcp_mm, length_mm: float, model_mm: float, dial_mm: float
    ) -> None:
        """One stored sample: where the nominal model puts the TCP and the live error."""
        self.rec.set_time("sample", sequence=index)
        self.rec.set_time("session_time", duration=t_s)
        tcp = np.asarray(tcp_mm, float)
        error = length_mm - model_mm
        color = GREEN if abs(error) <= self.ok_mm else RED
        self._path.append(tcp)
        self.rec.log("cell/path", rr.LineStrips3D([np.array(self._path)], radii=0.8, colors=[GREY]))
        self.rec.log(
            "cell/sample",
            rr.Points3D([tcp], radii=6.0, colors=[color], labels=[f"#{index}: {error:+.3f} mm"]),
        )
        self.rec.log(
            "cell/cable", rr.LineStrips3D([np.array([self._anchor, tcp])], radii=1.0, colors=[color])
        )
        self.rec.log("live/length/reading", rr.Scalars(length_mm))
        self.rec.log("live/length/model", rr.Scalars(model_mm))
        self.rec.log("live/error", rr.Scalars(error))
        if np.isfinite(dial_mm):
            self.rec.log("live/dial", rr.Scalars(dial_mm))

    def message(self, text: str) -> None:
        level = (
            rr.TextLogLevel.WARN
            if text.startswith(("suspended", "capture", "timed"))
            else rr.TextLogLevel.INFO
        )
        self.rec.log("log", rr.TextLog(text, level=level))

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


def _has_display() -> bool:
    return sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
