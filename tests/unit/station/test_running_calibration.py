"""The running calibration on simulated sessions: live errors against the refits (no jump at a new
line, noise-level within a line, a bad reading called suspect), the predicted workspace error as
the lines grow, the saturation message and the --until-mm goal; and, on the session engine's
simulated clock, that a slow refit never delays a capture (refits coalesce instead).

The refits are the real pipeline (``station.jobs.running.refit``), run in this process by stand-in
workers that answer late: ``LaggingWorker`` a few samples after a job starts (as the demo's worker
does), ``ClockedWorker`` after a time on the session's clock.
"""

from __future__ import annotations

import io
import signal
import time
from types import SimpleNamespace

import numpy as np
import pytest

import configs
from sim_fixtures.world import World
from station.acquire import runner
from station.acquire.capture import Devices
from station.acquire.livefit import WORKER_ENDED, FitFailed, FitWorker, LiveListener, RunningCalibration
from station.acquire.progress import Progress
from station.acquire.session import Session, State
from station.formats.plan import Plan
from station.formats.session_folder import SessionFolder
from station.formats.tables import load_robot, load_setup
from station.jobs.running import refit
from station.view.live import LiveView
from tests.unit.station.test_session_engine import (  # noqa: F401
    BACKOFF,
    PLAN,
    RULES,
    T0_WALL,
    Cell,
    clock,
    timeline,
    walk,
)

ROBOT = load_robot(configs.path("robots/hsr_jr680.toml"))
SETUP = load_setup(configs.path("setups/sim.toml"))
PER_LINE = (70, 25, 25)  # samples on lines 0, 1, 2, in this order
BAD = PER_LINE[0] + PER_LINE[1] + 10  # this sample's drawstring reads 0.3 mm long (cable slip), on line 2
NOISE_MM = 0.02  # the simulated drawstring, one reading per sample
LAG = 3  # samples taken while a refit runs
GOAL_MM = 1.0  # --until-mm


class LaggingWorker:
    """Runs each job at once but answers only after ``lag`` more samples were added."""

    ended = False

    def __init__(self, lag: int):
        self.lag, self.busy, self.jobs = lag, False, []
        self._answer, self._due = None, 0
        self.added = 0

    def submit(self, kind, samples):
        self.jobs.append((kind, len(samples)))
        self._answer = (kind, _run(kind, samples))
        self._due, self.busy = self.added + self.lag, True

    def poll(self, timeout_s: float = 0.0):
        if not self.busy or self.added < self._due:
            return None
        self.busy = False
        return self._answer

    def close(self):
        pass


def _run(kind, samples):
    assert kind == "refit"  # the plan here always has a next line to name
    return refit(ROBOT, SETUP, samples)


@pytest.fixture(scope="module")
def session():
    """A simulated session fed sample by sample: live errors, suspects, refits and messages."""
    world = World.create(0)
    q, lines = world.line_configurations(max(PER_LINE), np.random.default_rng(1))
    keep = np.concatenate([np.flatnonzero(lines == k)[:n] for k, n in enumerate(PER_LINE)])
    s = world.measure(q[keep], lines[keep], np.random.default_rng(2))
    s.length_mm[BAD] += 0.3
    out = {"messages": [], "refits": [], "reached": []}
    listener = LiveListener(out["refits"].append, out["messages"].append, out["reached"].append)
    worker = LaggingWorker(LAG)
    running = RunningCalibration(ROBOT, SETUP, worker, np.repeat([0, 1, 2], 4), listener, until_mm=GOAL_MM)
    live = []
    for i in range(len(s)):
        live.append(running.live_error(s.q_deg[i], s.length_mm[i]))
        running.add(s.q_deg[i], s.length_mm[i], s.dial_mm[i], s.line[i])
        worker.added += 1
        running.poll()
    out.update(live=live, line=s.line, worker=worker)
    return out


def _errors(session) -> np.ndarray:
    return np.array([np.nan if e.error_mm is None else e.error_mm for e in session["live"]])


def test_live_error_starts_with_the_first_judged_refit_and_says_how_far_off_that_is(session):
    errors, live = _errors(session), session["live"]
    first = next(f for f in session["refits"] if f.judged)  # answered LAG samples after it started
    known = np.isfinite(errors)
    assert not known[: first.n + LAG].any() and known[first.n + LAG :].all()
    assert (live[0].fitted, live[0].needed) == (None, None)  # no refit yet
    assert (live[LAG + 1].fitted, live[LAG + 1].needed) == (1, session["refits"][0].needed)
    assert all(e.limit_mm is not None for e in live[first.n + LAG :])


def test_live_error_has_no_jump_at_a_new_line_and_is_at_the_noise_within_a_line(session):
    errors, line = _errors(session), session["line"]
    assert np.nanmax(np.abs(errors)) < 10.0
    firsts = [int(np.flatnonzero(line == k)[0]) for k in (1, 2)]
    assert all(abs(errors[i]) < 10.0 for i in firsts)
    # once the refits hold ten samples of a line (3 more were taken while they ran), the prediction
    # is good to the noise (0.02 mm): a 0.1 mm error stands out
    settled = [i for i in range(len(line)) if i != BAD and np.sum(line[:i] == line[i]) >= 10 + LAG]
    assert np.nanmax(np.abs(errors[settled])) < 5 * NOISE_MM


def test_a_bad_reading_is_suspect_and_no_good_one_is(session):
    suspects = [i for i, e in enumerate(session["live"]) if e.suspect]
    assert suspects == [BAD]
    assert session["live"][BAD].limit_mm < 10 * NOISE_MM


def test_predicted_workspace_error_shrinks_from_one_line_to_three(session):
    judged = [(f.n, f.workspace.predicted_rmse_mm) for f in session["refits"] if f.workspace is not None]
    first_n, first = judged[0]
    assert first_n <= PER_LINE[0] and first > 1.0  # one line: millimetres
    assert judged[-1][1] < first / 5  # three lines
    assert all(f.workspace is None for f in session["refits"] if f.n < f.needed)


def test_a_line_that_stopped_paying_is_named_once_with_the_plans_next_line(session):
    said = [m for m in session["messages"] if "saturated" in m]
    assert len(said) == 1 and said[0].startswith("line 0 saturated at ")
    assert "next: line 1 of the plan (through [-1050, -450, 450] mm along [1.00, 0.00, 0.00])" in said[0]


def test_the_goal_is_reached_once_with_the_bound_met(session):
    assert len(session["reached"]) == 1
    first_met = next(
        f
        for f in session["refits"]
        if f.workspace is not None and f.workspace.predicted_rmse_95_mm <= GOAL_MM
    )
    assert f"after {first_met.n} samples" in session["reached"][0]


def test_refits_coalesce_when_they_fall_behind(session):
    counts = [n for _, n in session["worker"].jobs]
    assert counts == sorted(set(counts)) and counts[0] == 1
    assert np.all(np.diff(counts)[1:] == LAG)  # each refit takes every sample stored while the last ran


class ClockedWorker:
    """Runs each job at once but answers ``fit_s`` seconds of the session's clock later."""

    ended = False

    def __init__(self, session_clock, fit_s: float):
        self.clock, self.fit_s = session_clock, fit_s
        self.busy, self.jobs = False, []

    def submit(self, kind, samples):
        self.jobs.append((self.clock(), len(samples)))
        self._answer, self._due, self.busy = (
            (kind, refit(ROBOT, SETUP, samples)),
            self.clock() + self.fit_s,
            True,
        )

    def poll(self, timeout_s: float = 0.0):
        if self.busy and self.clock() < self._due <= self.clock() + timeout_s:
            self.clock.sleep(self._due - self.clock())  # a caller that waits: on the session's time
        if not self.busy or self.clock() < self._due:
            return None
        self.busy = False
        return self._answer

    def close(self):
        pass


def test_a_slow_refit_never_delays_a_capture(tmp_path, clock):  # noqa: F811
    """The station's wiring (``runner.Live``) on the session engine: captures land as with no
    refit while each refit takes 6 s of session time; a wiring that waited for refits would not."""
    world = World.create(0)
    q, lines = world.line_configurations(4, np.random.default_rng(1))
    plan = Plan.of(q, lines)
    cell = Cell(tmp_path, clock, timeline(*walk(plan.q_deg)), plan=plan)
    cell.drawstring.script = lambda t: {"length_mm": world.true_length_mm(cell.robot.script(t)["q_deg"])[0]}
    worker = ClockedWorker(clock, fit_s=6.0)  # a refit takes over two targets' time
    view = LiveView(tmp_path / "session.rrd")
    live = runner.Live(
        ROBOT, SETUP, plan.line, worker, view, Progress(len(plan), stream=io.StringIO(), clock=clock), None
    )
    assert cell.session(live.listener()).run() is State.DONE
    view.close()
    # every capture settle_s after the robot arrives, as with no refit (2.5 s a target, 0.5 s moving)
    arrived = 0.5 + 2.5 * np.arange(len(plan))
    t_s = np.array([float(r["t_s"]) for r in cell.folder.rows])
    late_s = t_s - arrived - RULES.settle_s
    assert np.all((late_s >= 0) & (late_s < 3 * RULES.poll_s))
    # refits coalesced: each took every sample stored when it started, one at a time
    starts = np.array([t for t, _ in worker.jobs]) - (T0_WALL - cell.folder.header["start_wall_s"])
    assert [n for _, n in worker.jobs] == [int(np.searchsorted(t_s, t, side="right")) for t in starts]
    assert np.all(np.diff(starts) >= worker.fit_s) and 1 < len(worker.jobs) < len(plan)


def test_the_log_says_once_why_the_live_error_waits_and_once_when_it_starts(session):
    waiting = [m for m in session["messages"] if "start once the samples determine the model" in m]
    started = [m for m in session["messages"] if "the model is determined by" in m]
    first = next(f for f in session["refits"] if f.judged)
    assert len(waiting) == 1
    assert f"(1 of {session['refits'][0].needed} so far; the number needed grows" in waiting[0]
    assert started == [f"running calibration: the model is determined by {first.n} samples"]


class Pipe:
    """The station's end of a worker's pipe, in memory: ``answers`` to receive in order; ``gone``
    as once the worker process died (a send breaks, a receive finds the end of the pipe)."""

    def __init__(self, *answers):
        self.answers, self.sent, self.gone = list(answers), [], False

    def send(self, obj):
        if self.gone:
            raise BrokenPipeError(32, "Broken pipe")
        self.sent.append((obj[0], len(obj[1])))

    def poll(self, timeout_s=0.0):
        return bool(self.answers) or self.gone

    def recv(self):
        if not self.answers:
            raise EOFError
        return self.answers.pop(0)

    def close(self):
        pass


class Process:
    def terminate(self):
        pass

    def join(self, timeout=None):
        pass


def _calibration(pipe: Pipe):
    messages = []
    worker = FitWorker(pipe, Process())
    running = RunningCalibration(ROBOT, SETUP, worker, np.zeros(1), LiveListener(message=messages.append))
    return running, worker, messages


def _add(running: RunningCalibration, n: int = 1) -> None:
    for _ in range(n):
        running.add([10.0, -30.0, 40.0, 0.0, 20.0, 5.0], 1200.0, 0.0, 0)


@pytest.mark.parametrize("dies", ["while idle", "during a refit"])
def test_a_dead_worker_stops_the_running_calibration_with_one_message_and_the_session_goes_on(dies):
    pipe = Pipe(("ready", None))
    running, worker, messages = _calibration(pipe)
    assert worker.wait_ready(0.0)
    if dies == "during a refit":
        _add(running)
        assert worker.busy and pipe.sent == [("refit", 1)]
    pipe.gone = True
    for _ in range(3):
        _add(running)
        assert running.poll() is None
    assert messages == [WORKER_ENDED]
    assert worker.ended and not worker.busy  # a drain returns at once
    assert len(pipe.sent) == (dies == "during a refit")  # no job after the first that found it gone


def test_a_failed_refit_is_tried_again_only_once_more_samples_came():
    pipe = Pipe(("ready", None))
    running, worker, messages = _calibration(pipe)
    worker.wait_ready(0.0)
    _add(running, 2)  # the second sample waits for the first's refit
    pipe.answers.append(("refit", FitFailed("LinAlgError: SVD did not converge")))
    for _ in range(3):
        running.poll()
    assert pipe.sent == [("refit", 1), ("refit", 2)]  # the second started when the first failed
    pipe.answers.append(("refit", FitFailed("LinAlgError: SVD did not converge")))
    for _ in range(3):
        running.poll()
    assert pipe.sent == [("refit", 1), ("refit", 2)] and not worker.busy
    assert messages == ["running calibration: refit failed: LinAlgError: SVD did not converge"] * 2
    _add(running)
    assert pipe.sent[-1] == ("refit", 3)


def test_samples_added_while_the_worker_starts_are_refitted_once_it_is_ready():
    pipe = Pipe()
    running, worker, _ = _calibration(pipe)
    _add(running, 2)
    assert running.poll() is None and pipe.sent == []  # still starting
    pipe.answers.append(("ready", None))
    running.poll()
    assert pipe.sent == [("refit", 2)] and worker.busy  # a drain now waits for it


class UnansweredWorker:
    """A worker whose refit never answers; its first poll delivers a SIGTERM to this process (a
    service manager stopping the station while the session's end waits for the refit)."""

    busy = ended = False
    polls = 0

    def wait_ready(self, timeout_s):
        return True

    def poll(self, timeout_s=0.0):
        self.polls += 1
        if self.polls == 1:
            signal.raise_signal(signal.SIGTERM)
        return None

    def close(self):
        pass


def test_a_signal_ends_the_wait_for_the_final_refit_and_the_session_keeps_its_state(tmp_path, monkeypatch):
    worker = UnansweredWorker()

    class EndedSession(Session):
        def run(self):
            worker.busy = True  # the refit on the last sample runs
            return State.DONE

    monkeypatch.setattr(runner, "Session", EndedSession)
    monkeypatch.setattr(runner, "FINAL_FIT_S", 3.0)  # a failing test waits this long, not 30 s
    folder = SessionFolder.new(tmp_path / "s", {"start_wall_s": T0_WALL})
    folder.make()
    inputs = runner.SessionInputs(folder, SimpleNamespace(session=None, time_scale=1.0), PLAN, ROBOT, SETUP)
    monkeypatch.setattr(runner.Rules, "from_config", staticmethod(lambda *_: RULES))
    view = LiveView(tmp_path / "session.rrd")
    live = runner.Live(ROBOT, SETUP, PLAN.line, worker, view, Progress(len(PLAN), stream=io.StringIO()), None)
    assert runner._run_session(inputs, Devices({}, BACKOFF), live) is State.DONE
    view.close()
    assert worker.polls == 1  # the signal's stop request ended the wait at once


def test_a_worker_started_with_the_plan_corrects_it_with_every_judged_refit_and_only_those():
    """The real worker process: each judged refit carries the plan's corrected targets, heard by the
    listener's ``corrected``; an undetermined one carries none."""
    world = World.create(0)
    q, lines = world.line_configurations(12, np.random.default_rng(1))
    s = world.measure(q, lines, np.random.default_rng(2))
    heard = []
    listener = LiveListener(corrected=heard.append)
    worker = FitWorker.start(ROBOT, SETUP, (q, lines))
    running = RunningCalibration(ROBOT, SETUP, worker, lines, listener)
    try:
        assert worker.wait_ready(30.0)
        for n in (10, len(s)):  # too few to determine the model, then all
            for i in range(len(running.samples), n):
                running.add(s.q_deg[i], s.length_mm[i], s.dial_mm[i], s.line[i])
            deadline = time.monotonic() + 120.0
            while (running.latest is None or running.latest.n < n) and time.monotonic() < deadline:
                running.poll(1.0)  # a refit on the samples so far, then one on all of them
            assert running.latest.n == n
        assert len(running.history) == 1 and running.latest.judged  # one judged refit, the last
        assert len(heard) == 1 and heard[0].n == len(s) and heard[0].q_deg.shape == q.shape
        assert heard[0].ok.all() and np.abs(heard[0].q_deg - q).max() < 2.0  # small corrections
    finally:
        running.close()


def test_a_correction_that_fails_leaves_the_refit_standing_and_is_said_once(monkeypatch):
    from station.acquire import livefit

    world = World.create(0)
    q, lines = world.line_configurations(12, np.random.default_rng(1))
    s = world.measure(q, lines, np.random.default_rng(2))
    samples = SimpleNamespace(q_deg=s.q_deg, length_mm=s.length_mm, dial_mm=s.dial_mm, line=s.line)

    def broken(*args):
        raise np.linalg.LinAlgError("singular matrix")

    monkeypatch.setattr(livefit, "correct_targets", broken)
    fit = livefit._job("refit", ROBOT, SETUP, livefit.SessionSamples(**vars(samples)), (q, lines))
    assert fit.judged and isinstance(fit.targets, FitFailed)
    said, heard = [], []
    worker = SimpleNamespace(
        busy=False, ended=False, poll=lambda t=0.0: ("refit", fit), submit=lambda *a: None
    )
    running = RunningCalibration(
        ROBOT, SETUP, worker, lines, LiveListener(message=said.append, corrected=heard.append)
    )
    for k in range(len(s)):
        running.add(s.q_deg[k], s.length_mm[k], s.dial_mm[k], s.line[k])
    running.poll()
    running.poll()
    assert running.latest is fit and heard == []
    assert [m for m in said if "correcting" in m] == [
        "running calibration: correcting the targets failed: LinAlgError: singular matrix"
    ]
