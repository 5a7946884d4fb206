"""A sweep session (issue 37): the plan has passes, the robot slides the tool along each gauge edge
through a pass's waypoints without stopping, and the station streams every device
(``station.acquire.stream``) and aligns the readings onto one time base.

Rows. One row per drawstring reading (decimated to ``[sweep] rows_per_s`` per simulated second:
of the readings in each slot the one whose timing leaves its length least uncertain, see flags),
taken while the robot sweeps a pass: its time ``t`` is the middle of the reading's request and
reply moved back by the drawstring's stated latency (``[sweep] drawstring_latency_s``), the moment
the length it reports was true. The joints there are interpolated linearly between the robot's two
packages around ``t`` (the controller's timestamps, tied to the station's clock by the least
transit: ``calib.alignment``), the dial between its two readings around ``t`` (each moved back by
the dial's stated latency). ``target``: the pass's waypoint nearest (joint space) to the row's
joints, so ``target`` and ``line`` keep their meaning and ``pass`` says which sweep; ``t_s`` is
``t`` in seconds since the session started; ``q_spread_deg``: how far the joints moved between the
two packages interpolated; ``window_s``: the reading's round trip [s].

Flags: a row is stored in ``flagged.csv`` with its reason, never in ``samples.csv``, where

- the dial answered out of range around it (``dial off the edge``: lifted off, or off the line),
  read outside ``[session] dial_range_mm`` (``dial outside its gate``), gave no reading within
  ``[sweep] max_gap_s`` of it (``no dial reading``), or changed between its readings around it so
  that interpolating them may be off by more than ``[sweep] timing_share`` of the setup's
  ``line_sigma_mm`` (``dial changing fast``: ``calib.alignment.interpolation_error``; the tool
  landing on or leaving the edge, a reading beside a lift-off: off by up to 1.6 mm in a demo sweep
  before this rule);
- the TCP moved faster along the edge than ``[sweep] max_speed_mm_s`` (``too fast``: the nominal
  model's TCP speed from the joints and joint speeds);
- the robot's packages around it lie farther apart than ``max_gap_s`` or its mode is not RUNNING
  (``no robot data``), or the drawstring read outside ``length_range_mm`` or answered with an error;
- its length is uncertain from its timing alone by more than ``[sweep] timing_share`` of the
  drawstring's stated noise (``timing uncertain``): the device measured somewhere in the reading's
  round trip (half of it, times the nominal length's rate there) and the joints are interpolated
  linearly between two packages (``h/8`` times the change of that rate across them, ``h`` the
  packages' gap: linear interpolation's bound). A busy station's late replies and stalled robot
  packages make these rows (issue 37: their lengths off by up to 0.5 mm at 0.02 mm noise).

Passes. The robot is on a pass while it is where :class:`PassMap` says (its nominal TCP near the
pass's polyline, its joints within ``[session] match_deg`` of the waypoints' range); a pass is
finished once the robot has been on it from its first waypoint to its last without leaving: then
its rows are aligned and appended at once (``SessionFolder.append_rows``) and ``session.toml``'s
``finished_passes`` updated. ``--resume`` drops the rows of a pass not in that list (a crash
mid-append) and waits for the first unfinished pass. A pass the robot leaves half-way is not
stored; the program's next round sweeps it again; so is one where more than ``MISSED_SHARE`` of
the readings fell in the station's own gaps (no robot data, no dial reading: a busy station).

Latency: at the end the drawstring's latency is estimated from the stored rows
(``calib.alignment.estimate_lag`` against the nominal kinematics and the setup's anchor) and checked
against the stated one; a difference beyond ``latency_tolerance_s`` and three standard errors is
named in one line (an estimate whose three standard errors exceed the tolerance is said to be too
uncertain to check). The dial's latency is not estimated: it reads the tool's error across the
edge, which barely changes along a pass; the session says about how far a latency
``latency_tolerance_s`` off would move its rows at its trend's steepest (``calib.alignment.steepest_rate``:
a per-pass cubic's, an estimate, not a bound: the true dial may change faster at places). A sensor
that leaves over ``DROP_NOTE`` of its requests unanswered is named; its missing readings are missing
rows, never filled in.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calib.alignment import Lag, clock_offset, estimate_lag, interpolate, interpolation_error, steepest_rate
from calib.kinematics import tcp_position
from calib.params import dh_from_degrees
from errors import DeviceError
from station.acquire.capture import RUNNING
from station.acquire.session import State
from station.acquire.stream import Streams
from station.config import StationConfig
from station.formats.plan import Plan
from station.formats.session_folder import SessionFolder

TICK_S = 0.05  # real s between looks at the streams
MATCH_MM = 20.0  # nominal TCP to a pass's polyline: on the pass (the nominal TCP of the true joints lies
# off the plan's by the robot's own error, up to about 10 mm on the demo's cells; the joint ranges tell
# passes apart)
END_TOL = 0.25  # of a segment: how close to a pass's first and last waypoint the robot must come
SPEED_STEP_S = 1e-3  # simulated s: the finite step of the TCP speed
SIGMAS = 3  # an estimated latency this many standard errors (and the tolerance) off is named
DROP_NOTE = 0.01  # a sensor leaving more of its requests unanswered is named
MISSED = ("no robot data", "no dial reading")  # the station's gaps, not the tool's
MISSED_SHARE = 0.5  # a pass the station missed more of is swept again


@dataclass(frozen=True)
class SweepRules:
    """The sweep's rule in real seconds (the config's simulated ones divided by ``time_scale``);
    speeds per simulated second, as the controller reports them."""

    time_scale: float
    latency_s: dict[str, float]
    max_speed_mm_s: float
    max_gap_s: float
    row_spacing_s: float
    tolerance_s: float  # simulated
    timing_limit_mm: float  # a row's length uncertain from its timing by more is flagged
    dial_limit_mm: float  # a row's dial uncertain from its interpolation by more is flagged
    dial_range_mm: tuple[float, float]
    length_range_mm: tuple[float, float]
    match_deg: float
    target_timeout_s: float
    unreachable_s: float

    @classmethod
    def from_config(cls, cfg: StationConfig, sigma_mm: float, line_sigma_mm: float) -> SweepRules:
        """The rules of ``cfg``, for a drawstring of noise ``sigma_mm`` and a tool held to the
        edge within ``line_sigma_mm`` (the setup's) [mm, 1 sigma]."""
        sw, se, k = cfg.sweep, cfg.session, cfg.time_scale
        return cls(
            time_scale=k,
            latency_s={"drawstring": sw.drawstring_latency_s / k, "dial": sw.dial_latency_s / k},
            max_speed_mm_s=sw.max_speed_mm_s,
            max_gap_s=sw.max_gap_s / k,
            row_spacing_s=1.0 / (sw.rows_per_s * k),
            tolerance_s=sw.latency_tolerance_s,
            timing_limit_mm=sw.timing_share * sigma_mm,
            dial_limit_mm=sw.timing_share * line_sigma_mm,
            dial_range_mm=tuple(se.dial_range_mm),
            length_range_mm=tuple(se.length_range_mm),
            match_deg=se.match_deg,
            target_timeout_s=se.target_timeout_s / k,
            unreachable_s=se.unreachable_s,
        )


class Kinematics:
    """The nominal robot's TCP [mm] and the drawstring's nominal length [mm] (to the setup's
    anchor), for joints [deg]."""

    def __init__(self, robot, setup):
        self.dh = dh_from_degrees(robot.table_deg())
        self.tool = np.asarray(robot.tool_mm, float)
        self.anchor = np.asarray(setup.drawstring.anchor_mm, float)

    def tcp(self, q_deg) -> np.ndarray:
        return tcp_position(self.dh, np.radians(np.atleast_2d(q_deg)), self.tool)

    def speed(self, q_deg, qd_deg_s) -> np.ndarray:
        """TCP speed [mm per the joint speeds' second]."""
        ahead = self.tcp(q_deg + qd_deg_s * SPEED_STEP_S)
        return np.linalg.norm(ahead - self.tcp(q_deg), axis=1) / SPEED_STEP_S

    def length(self, q_deg) -> np.ndarray:
        return np.linalg.norm(self.tcp(q_deg) - self.anchor, axis=1)

    def length_rate(self, q_deg, qd_deg_s) -> np.ndarray:
        """The drawstring's length rate [mm per the joint speeds' second]."""
        return (self.length(q_deg + qd_deg_s * SPEED_STEP_S) - self.length(q_deg)) / SPEED_STEP_S


class PassMap:
    """Where the robot is on a sweep plan's passes: its nominal TCP within ``MATCH_MM`` of the
    polyline through a pass's waypoints' nominal TCPs, and its joints within ``match_deg`` of the
    range the two waypoints of that segment span (each joint: a joint-linear chord may stray from the
    robot's path between waypoints; the range does not, and it keeps another IK branch out)."""

    def __init__(self, plan: Plan, match_deg: float, kin: Kinematics):
        self.rows = plan.passes()
        self.ids = [int(plan.sweep_pass[r[0]]) for r in self.rows]
        self.match_deg, self.kin = match_deg, kin
        tcp = kin.tcp(plan.q_deg)
        a, b, qa, qb, owner, k = [], [], [], [], [], []
        for p, rows in enumerate(self.rows):
            pair = (rows[:-1], rows[1:]) if len(rows) > 1 else (rows, rows)
            a.append(tcp[pair[0]])
            b.append(tcp[pair[1]])
            qa.append(plan.q_deg[pair[0]])
            qb.append(plan.q_deg[pair[1]])
            owner += [p] * len(pair[0])
            k += list(range(len(pair[0])))
        self.a, self.b = np.vstack(a), np.vstack(b)
        self.q_low = np.minimum(np.vstack(qa), np.vstack(qb)) - match_deg
        self.q_high = np.maximum(np.vstack(qa), np.vstack(qb)) + match_deg
        self.owner, self.k = np.array(owner), np.array(k, float)
        self.segments = [max(len(r) - 1, 0) for r in self.rows]

    def locate(self, q_deg: np.ndarray, prefer: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The pass (index into :attr:`rows`; -1: none) of joints (N, 6) [deg] and the position
        along it (segments from its first waypoint); where pass ``prefer`` (the one the robot is on)
        matches too, that one (two passes along one edge may both match where they cross)."""
        q = np.atleast_2d(q_deg)
        p = self.kin.tcp(q)[:, None, :]
        way = self.b - self.a
        norm = np.maximum(np.einsum("sj,sj->s", way, way), 1e-12)
        u = np.clip(np.einsum("nsj,sj->ns", p - self.a, way) / norm, 0.0, 1.0)
        dist = np.linalg.norm(p - self.a - u[..., None] * way, axis=2)
        inside = np.all((q[:, None] >= self.q_low) & (q[:, None] <= self.q_high), axis=2)
        dist = np.where(inside, dist, np.inf)
        if prefer is not None and prefer >= 0:
            dist = np.where((self.owner == prefer) & (dist <= MATCH_MM), dist - 2 * MATCH_MM, dist)
        best = np.argmin(dist, axis=1)
        n = np.arange(len(best))
        found = dist[n, best] <= MATCH_MM
        return np.where(found, self.owner[best], -1), self.k[best] + u[n, best]


@dataclass
class _Run:
    """The robot on pass ``p`` since ``t0`` [s, station clock]: the farthest back and on it reached."""

    p: int
    t0: float
    t1: float
    low: float
    high: float

    def covers(self, segments: int, min_s: float) -> bool:
        if segments == 0:
            return self.t1 - self.t0 >= min_s
        return self.low <= END_TOL and self.high >= segments - END_TOL


class SweepSession:
    """Run a sweep ``plan`` against ``drivers`` into ``folder`` under ``rules``; ``robot``, ``setup``:
    the nominal model and the setup (for speeds, positions and the latency check); ``tell(text)``
    says what happens, ``show(pass_id, line, tcp_good, tcp_flagged, t_s, sample=, passes=)`` draws a
    stored pass (``sample``: its last row's index; ``passes``: done and total) and ``trail(tcp, t_s,
    sample)`` where the tool slid on a pass since the last look (nominal TCPs (N, 3); ``sample``: the
    index its first row will take)."""

    def __init__(
        self,
        folder: SessionFolder,
        plan: Plan,
        streams: Streams,
        rules: SweepRules,
        kin: Kinematics,
        tell: Callable[[str], None] = lambda text: None,
        show: Callable[..., None] = lambda *a, **k: None,
        trail: Callable[[np.ndarray, float, int], None] = lambda tcp, t_s, sample: None,
    ):
        self.folder, self.plan, self.streams, self.rules, self.kin = folder, plan, streams, rules, kin
        self.tell, self.show, self.trail = tell, show, trail
        self.map = PassMap(plan, rules.match_deg, kin)
        self.finished = {int(p) for p in folder.header.get("finished_passes", [])}
        self.pending = [p for p, pid in enumerate(self.map.ids) if pid not in self.finished]
        self.flag_counts: Counter[str] = Counter()
        self.offset = np.inf  # station clock minus the controller's [s]
        self._seen = 0  # robot packages looked at
        self._run: _Run | None = None
        self._stop = False
        self._mono0 = time.monotonic()
        self._wall_minus_mono = time.time() - self._mono0
        self._t0_wall = float(folder.header["start_wall_s"])
        self._lag_rows: list[tuple] = []  # (t, length, pass, position) of every stored row
        self._dial_rows: list[tuple] = []  # (t, dial, pass) of every stored row
        self._span: list[float] = []  # station times [s] of the stored passes' starts and ends
        self._next_sample = folder.next_sample  # the index the next stored row takes (the view's time)

    def request_stop(self) -> None:
        self._stop = True

    @property
    def stop_requested(self) -> bool:
        return self._stop

    def run(self) -> State:
        """Until every pass is stored, a stop request, or ``target_timeout_s`` without a pass."""
        self.streams.start()
        last = time.monotonic()
        try:
            while self.pending:
                if self._stop:
                    return self._end(State.STOPPED, "stopped on request")
                time.sleep(TICK_S)
                if self._tick():
                    last = time.monotonic()
                self._check_devices()
                if time.monotonic() - last > self.rules.target_timeout_s:
                    waited = self.rules.target_timeout_s * self.rules.time_scale
                    left = ", ".join(str(self.map.ids[p]) for p in self.pending[:10])
                    return self._end(
                        State.TIMED_OUT, f"no pass swept whole for {waited:g} s; left: pass {left}"
                    )
            return self._end(State.DONE, f"all {len(self.map.ids)} passes swept")
        finally:
            self.streams.stop()

    def _tick(self) -> bool:
        """Look at the robot's new packages: True if a pass was stored."""
        robot = self.streams.robot.arrays()
        if len(robot["arrival"]) < self._seen:  # the stream started again on the station's clock
            self._seen, self.offset, self._run = 0, np.inf, None
        new = slice(self._seen, len(robot["arrival"]))
        if new.start == new.stop:
            return False
        self._seen = new.stop
        if self.streams.robot.stamped:
            self.offset = min(self.offset, clock_offset(robot["stamp"][new], robot["arrival"][new]))
        else:
            self.offset = 0.0
        t = robot["stamp"][new] + self.offset
        where, pos = self.map.locate(robot["q_deg"][new], None if self._run is None else self._run.p)
        where[robot["mode"][new] != RUNNING] = -1
        if np.any(where >= 0):
            self.trail(
                self.kin.tcp(robot["q_deg"][new][where >= 0]),
                float(t[-1] + self._wall_minus_mono - self._t0_wall),
                self._next_sample,
            )
        stored = False
        for ti, p, u in zip(t, where, pos, strict=True):
            run = self._run
            if run is not None and run.p == p:
                run.t1, run.low, run.high = ti, min(run.low, u), max(run.high, u)
                continue
            if run is not None:
                stored |= self._close(run, robot)
            self._run = _Run(int(p), ti, ti, u, u) if p >= 0 else None
        return stored

    def _close(self, run: _Run, robot: dict) -> bool:
        """The robot left pass ``run.p``: store it if it swept it whole and it is unfinished."""
        if run.p not in self.pending:
            return False
        if not run.covers(self.map.segments[run.p], 0.5 / self.rules.time_scale):
            return False
        return self._store(run, robot)

    def _store(self, run: _Run, robot: dict) -> bool:
        """Store a swept pass (True), unless the station missed most of it (``MISSED``): then it
        is left for the program's next round."""
        rows, flagged, tcp = self._rows(run, robot)
        missed = sum(r["reason"] in MISSED for r in flagged)
        line = int(self.plan.line[self.map.rows[run.p][0]])
        if missed > MISSED_SHARE * (len(rows) + len(flagged)):
            self.tell(
                f"pass {self.map.ids[run.p]} (line {line}): the station missed {missed} of its "
                f"{len(rows) + len(flagged)} readings (no robot data or no dial reading around them): "
                "nothing stored, it is taken when the robot sweeps it again"
            )
            return False
        self.folder.append_rows(rows, flagged)
        self._next_sample = self.folder.next_sample
        self._span += [run.t0, run.t1]
        pid = self.map.ids[run.p]
        self.finished.add(pid)
        self.pending.remove(run.p)
        self.folder.update_header(finished_passes=sorted(self.finished))
        reasons = Counter(r["reason"] for r in flagged)
        self.flag_counts.update(reasons)
        said = "; ".join(f"{n} {why}" for why, n in reasons.most_common())
        self.tell(
            f"pass {pid} (line {line}): {len(rows)} rows stored"
            + (f", {len(flagged)} flagged ({said})" if flagged else "")
            + f" ({len(self.finished)}/{len(self.map.ids)} passes)"
        )
        self.show(
            pid,
            line,
            tcp[: len(rows)],
            tcp[len(rows) :],
            rows[-1]["t_s"] if rows else 0.0,
            sample=self._next_sample - 1,
            passes=(len(self.finished), len(self.map.ids)),
        )
        return True

    def _rows(self, run: _Run, robot: dict) -> tuple[list[dict], list[dict], np.ndarray]:
        """The pass's rows and flagged rows (module notes), and the nominal TCP of each (rows
        first, flagged after)."""
        r, lat = self.rules, self.rules.latency_s
        t_read, length, trip = self.streams.sensors["drawstring"].arrays()
        on = (t_read >= run.t0 + lat["drawstring"]) & (t_read <= run.t1 + lat["drawstring"])
        t_read, length, trip = t_read[on], length[on], trip[on]
        times = robot["stamp"] + self.offset
        timing = self._timing_mm(times, robot, t_read - lat["drawstring"], trip)
        keep = _decimated(t_read, r.row_spacing_s, timing)
        t, length, trip, timing = t_read[keep] - lat["drawstring"], length[keep], trip[keep], timing[keep]
        q, q_ok = interpolate(times, robot["q_deg"], t, r.max_gap_s)
        qd, _ = interpolate(times, robot["qd_deg_s"], t, r.max_gap_s)
        stopped, _ = interpolate(times, (robot["mode"] != RUNNING).astype(float), t, r.max_gap_s)
        spread = _bracket_spread(times, robot["q_deg"], t)
        reason = np.full(len(t), "", dtype=object)
        reason[~(q_ok & (stopped[:, 0] == 0.0))] = "no robot data"  # 0 exactly: both packages RUNNING
        q_safe = np.where(np.isfinite(q), q, 0.0)
        speed = self.kin.speed(q_safe, np.where(np.isfinite(qd), qd, 0.0))
        low, high = r.length_range_mm
        _flag(reason, ~np.isfinite(length), "drawstring error")
        _flag(reason, np.isfinite(length) & ((length < low) | (length > high)), "drawstring outside its gate")
        _flag(reason, speed > r.max_speed_mm_s, "too fast")
        dial = self._dial(t, reason)
        _flag(reason, timing > r.timing_limit_mm, "timing uncertain")
        rows_p = self.map.rows[run.p]
        nearest = rows_p[np.argmin(np.max(np.abs(q_safe[:, None] - self.plan.q_deg[rows_p]), axis=2), axis=1)]
        wall = t + self._wall_minus_mono
        pid, line = self.map.ids[run.p], int(self.plan.line[rows_p[0]])
        tcp = self.kin.tcp(q_safe)
        rows, flagged, order = [], [], []
        for i in range(len(t)):
            cells = {
                "target": int(self.plan.target[nearest[i]]),
                "line": line,
                "pass": pid,
                **{f"q{j + 1}_deg": float(q_safe[i, j]) for j in range(6)},
                "length_mm": float(length[i]),
                "dial_mm": "" if not np.isfinite(dial[i]) else float(dial[i]),
                "t_s": float(wall[i] - self._t0_wall),
                "t_wall_s": float(wall[i]),
            }
            if reason[i]:
                flagged.append({"reason": reason[i], **cells, "speed_mm_s": float(speed[i])})
                continue
            order.append(i)
            rows.append(
                {
                    "sample": self.folder.next_sample + len(rows),
                    **cells,
                    "q_spread_deg": float(spread[i]),
                    "length_spread_mm": "",
                    "dial_spread_mm": "",
                    "window_s": float(trip[i]),
                }
            )
        good = np.array(order, int)
        along = _along(tcp[good])
        self._lag_rows += list(zip(t[good], length[good], [pid] * len(good), along, strict=True))
        self._dial_rows += list(zip(t[good], dial[good], [pid] * len(good), strict=True))
        bad = np.setdiff1d(np.arange(len(t)), good)
        return rows, flagged, np.vstack([tcp[good], tcp[bad]]) if len(t) else np.zeros((0, 3))

    def _timing_mm(self, times: np.ndarray, robot: dict, t: np.ndarray, trip: np.ndarray) -> np.ndarray:
        """How uncertain [mm] the length of readings at ``t`` [real s, robot packages at ``times``]
        with round trips ``trip`` [real s] is from their timing (module notes)."""
        left, right = _bracket(times, t)
        k = self.rules.time_scale
        rate = [self.kin.length_rate(robot["q_deg"][i], robot["qd_deg_s"][i]) for i in (left, right)]
        gap = (times[right] - times[left]) * k
        return np.maximum(*np.abs(rate)) * trip * k / 2 + np.abs(rate[1] - rate[0]) * gap / 8

    def _dial(self, t: np.ndarray, reason: np.ndarray) -> np.ndarray:
        """The dial at times ``t`` [s] (NaN without one), flagging ``reason`` (module notes)."""
        if "dial" not in self.streams.sensors:
            return np.full(len(t), np.nan)
        td, value, _ = self.streams.sensors["dial"].arrays()
        td = td - self.rules.latency_s["dial"]  # when each reading was true
        dial, ok = interpolate(td, value, t, self.rules.max_gap_s)
        dial = dial[:, 0]
        low, high = self.rules.dial_range_mm
        _flag(reason, ~ok, "no dial reading")
        _flag(reason, ok & ~np.isfinite(dial), "dial off the edge")
        _flag(reason, np.isfinite(dial) & ((dial < low) | (dial > high)), "dial outside its gate")
        _flag(reason, interpolation_error(td, value, t) > self.rules.dial_limit_mm, "dial changing fast")
        return dial

    def _check_devices(self) -> None:
        """A sensor that answered nothing for ``unreachable_s`` ends the session (DeviceError)."""
        now = time.monotonic()
        for s in self.streams.sensors.values():
            last = s.t[-1] if s.t else self._mono0
            if now - last > self.rules.unreachable_s:
                raise DeviceError(
                    f"{s.name} not answering for over {self.rules.unreachable_s:g} s ({s.last_failure}); "
                    f"{len(self.folder.rows)} rows kept"
                )

    def latency(self) -> Lag | None:
        """The drawstring's lag beyond its stated latency [real s] from the stored rows (None: too
        few rows or passes)."""
        if len(self._lag_rows) < 20:
            return None
        t, length, groups, along = (np.array(c) for c in zip(*self._lag_rows, strict=True))
        robot = self.streams.robot.arrays()
        times = robot["stamp"] + self.offset
        k = self.rules.time_scale

        def predict(at):
            q, _ = interpolate(times, robot["q_deg"], at, np.inf)
            qd, _ = interpolate(times, robot["qd_deg_s"], at, np.inf)
            step = SPEED_STEP_S / k  # real s
            now = self.kin.length(q)
            return now, (self.kin.length(q + qd * SPEED_STEP_S) - now) / step

        inside = (t > times[0] + 0.1) & (t < times[-1] - 0.1)
        return estimate_lag(predict, t[inside], length[inside], groups[inside], along[inside])

    def report(self) -> list[str]:
        """One line each: the drawstring's latency against the stated one, each sensor's
        unanswered requests, the rows flagged. ``session.toml`` gets them too, with ``robot_time_s``:
        the robot's (simulated) seconds from the first stored pass's start to the last one's end."""
        lines = []
        lag = self.latency()
        stated = self.rules.latency_s["drawstring"] * self.rules.time_scale
        if lag is not None:
            k = self.rules.time_scale
            est, sigma = stated + lag.lag_s * k, lag.sigma_s * k
            off = abs(lag.lag_s * k) > max(self.rules.tolerance_s, SIGMAS * sigma)
            if off:
                lines.append(
                    f"drawstring: latency stated {stated * 1e3:.1f} ms but the stream says "
                    f"{est * 1e3:.1f} +- {sigma * 1e3:.1f} ms ({lag.n} rows): the rows were aligned with the "
                    f"stated one; set [sweep] drawstring_latency_s = {est:.4f} and sweep again"
                )
            elif SIGMAS * sigma > self.rules.tolerance_s:
                lines.append(
                    f"drawstring: latency {est * 1e3:.1f} +- {sigma * 1e3:.1f} ms from {lag.n} rows: too "
                    f"uncertain to check the stated {stated * 1e3:.1f} ms (a busy station's timing)"
                )
            else:
                lines.append(
                    f"drawstring: latency {est * 1e3:.1f} +- {sigma * 1e3:.1f} ms estimated from {lag.n} "
                    f"rows, as stated ({stated * 1e3:.1f} ms)"
                )
            self.folder.update_header(
                latency={
                    "drawstring": {"stated_s": stated, "estimated_s": est, "sigma_s": sigma, "named": off}
                }
            )
        lines += self._dial_latency()
        for s in self.streams.sensors.values():
            if s.requests and s.unanswered / s.requests > DROP_NOTE:
                lines.append(
                    f"{s.name}: {s.unanswered} of {s.requests} requests unanswered "
                    f"({100 * s.unanswered / s.requests:.1f} %; last: {s.last_failure}): those readings are "
                    "missing, none filled in"
                )
        if self.flag_counts:
            said = ", ".join(f"{n} {why}" for why, n in self.flag_counts.most_common())
            lines.append(f"flagged (in flagged.csv, not samples): {said}")
        robot_s = (max(self._span) - min(self._span)) * self.rules.time_scale if self._span else 0.0
        self.folder.update_header(
            robot_time_s=robot_s,
            flagged=dict(self.flag_counts),
            unanswered={s.name: s.unanswered for s in self.streams.sensors.values()},
        )
        return lines

    def _dial_latency(self) -> list[str]:
        """What the dial's latency can do to its rows (its reading barely changes along a pass, so
        the stream cannot estimate it: module notes), one line; none without a dial or rows."""
        if "dial" not in self.streams.sensors or len(self._dial_rows) < 20:
            return []
        t, dial, groups = (np.array(c) for c in zip(*self._dial_rows, strict=True))
        k = self.rules.time_scale
        rate = steepest_rate(t * k, dial, groups)  # mm per simulated s
        stated, tolerance = self.rules.latency_s["dial"] * k, self.rules.tolerance_s
        moved = rate * tolerance
        dial = {"stated_s": stated, "steepest_mm_s": rate, "moved_mm_per_tolerance": moved}
        self.folder.update_header(latency={**self.folder.header.get("latency", {}), "dial": dial})
        return [
            f"dial: latency not estimated (its reading's trend changes by up to {rate:.3f} mm/s along "
            f"the passes: a latency {tolerance * 1e3:.1f} ms off moves its rows by about {moved * 1e3:.2f} "
            f"um); the stated {stated * 1e3:.1f} ms is used"
        ]

    def _end(self, state: State, text: str) -> State:
        self.tell(f"{state.value}: {text}; {len(self.folder.rows)} rows in {self.folder.path}")
        return state


def _flag(reason: np.ndarray, where: np.ndarray, why: str) -> None:
    """Give the rows ``where`` holds that have no reason yet the reason ``why``."""
    reason[where & (reason == "")] = why


def _decimated(t: np.ndarray, spacing_s: float, timing_mm: np.ndarray) -> np.ndarray:
    """Indices of one reading in each ``spacing_s`` [s] of ``t`` (increasing times; 0: all): the
    best timed (least ``timing_mm``, the first of equals), chosen by its timing alone, never its value."""
    if len(t) == 0 or spacing_s <= 0:
        return np.arange(len(t))
    slot = np.floor((t - t[0]) / spacing_s)
    order = np.lexsort((np.arange(len(t)), timing_mm, slot))
    _, first = np.unique(slot[order], return_index=True)
    return np.sort(order[first])


def _bracket(times, t) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the robot packages before and after each time ``t`` (the same one, without two)."""
    right = np.clip(np.searchsorted(times, t, side="right"), 1, max(len(times) - 1, 1))
    return np.minimum(right - 1, len(times) - 1), right if len(times) > 1 else right - 1


def _bracket_spread(times, q_deg, t) -> np.ndarray:
    """Max |dq| [deg] between the two robot packages around each time ``t``."""
    left, right = _bracket(times, t)
    return np.max(np.abs(q_deg[right] - q_deg[left]), axis=1)


def _along(tcp: np.ndarray) -> np.ndarray:
    """Position [mm] along a pass's principal direction of the TCPs ``tcp`` (N, 3)."""
    if len(tcp) < 2:
        return np.zeros(len(tcp))
    centred = tcp - tcp.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    return centred @ vt[0]
