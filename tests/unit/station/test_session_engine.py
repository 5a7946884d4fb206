"""The session engine on a simulated clock against in-memory devices: settle, capture, target
matching, suspend and resume, the target timeout, the unreachable limit, stop requests and resumed
sessions without duplicates. The socket and pty versions are in ``tests/system/test_session.py``.

Every device answers from a script of the (simulated) time; each read takes ``READ_S`` of it, and
the engine's waits advance it, so a test of minutes of session time runs in milliseconds.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pytest

from drivers.base import (
    Backoff,
    CrcError,
    DeviceReplyError,
    DeviceTimeout,
    Driver,
    Field,
    GarbledReply,
    Reading,
)
from errors import DeviceError
from station.acquire.capture import RUNNING, Capture, Devices, Rules
from station.acquire.session import ATTEMPTS_PER_TARGET, SUSPENDED_POLL_S, Listener, Session, State
from station.formats.plan import Plan
from station.formats.session_folder import SessionFolder

READ_S = 0.001  # simulated time one device read takes
T0_WALL = 1.7e9  # wall clock (s since the epoch) at simulated time 0
ANCHOR_MM = 1000.0  # the scripted drawstring reads ANCHOR_MM + q1 (deg): a truth per pose

RULES = Rules(
    settle_speed_deg_s=0.05,
    settle_s=0.5,
    readings=3,
    window_s=0.5,
    still_deg=0.005,
    jump_mm=0.15,
    dial_range_mm=(-2.0, 2.0),
    dial_stable_mm=0.02,
    length_range_mm=(50.0, 5000.0),
    match_deg=2.0,
    target_timeout_s=10.0,
    unreachable_s=5.0,
)
BACKOFF = Backoff(attempts=2, initial_s=0.05)
PLAN = Plan.of([[10.0 * i, -30.0, 40.0, 0.0, 20.0, 5.0] for i in range(3)], [0, 0, 1])


class FakeClock:
    """Simulated monotonic time (s): ``sleep`` advances it at once. A session still running after
    ``LIMIT_S`` of it would never end: that fails the test rather than hanging it."""

    LIMIT_S = 600.0

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds
        if self.now > self.LIMIT_S:
            raise AssertionError(f"the session still runs after {self.LIMIT_S:g} s of simulated time")


@pytest.fixture
def clock(monkeypatch):
    """The simulated clock; the real one fails the test if the engine reads or waits on it."""

    def real_clock(*_):
        raise AssertionError("the session engine used the real clock")

    monkeypatch.setattr(time, "monotonic", real_clock)
    monkeypatch.setattr(time, "sleep", real_clock)
    return FakeClock()


Script = Callable[[float], "dict | Exception"]


class ScriptedDriver(Driver):
    """A device in memory: ``read()`` at simulated time t answers ``script(t)`` (a dict of values)
    or raises it (a driver error); opens and closes are counted."""

    def __init__(self, name: str, fields: dict[str, Field], script: Script, clock: FakeClock):
        self.name, self.fields, self.script, self.clock = name, fields, script, clock
        self.reads = self.opens = self.closes = 0

    def open(self) -> None:
        self.opens += 1

    def close(self) -> None:
        self.closes += 1

    def read(self) -> Reading:
        self.clock.sleep(READ_S)
        self.reads += 1
        t = self.clock()
        answer = self.script(t)
        if isinstance(answer, Exception):
            raise answer
        units = {name: self.fields[name].units for name in answer}
        return Reading(self.name, answer, units, t_monotonic=t, t_wall=T0_WALL + t)


ROBOT_FIELDS = {
    "q_deg": Field("deg", (6,)),
    "qd_deg_s": Field("deg/s", (6,)),
    "robot_mode": Field(""),
    "package_age_s": Field("s"),
}


def still(q, mode: int = RUNNING) -> dict:
    return {"q_deg": tuple(q), "qd_deg_s": (0.0,) * 6, "robot_mode": mode}


def moving(q) -> dict:
    return {"q_deg": tuple(q), "qd_deg_s": (5.0,) * 6, "robot_mode": RUNNING}


def timeline(*segments) -> Script:
    """``(until_s, answer)`` segments in order; the last answer holds for ever after."""

    def at(t: float):
        for until, answer in segments:
            if t < until:
                return answer
        return segments[-1][1]

    return at


def walk(targets, arrive_s: float = 0.5, dwell_s: float = 2.0, start_s: float = 0.0) -> list:
    """Segments of a robot that, from ``start_s`` on, moves for ``arrive_s`` to each pose and
    holds it ``dwell_s``."""
    segments, t = [], start_s
    for q in targets:
        segments += [(t + arrive_s, moving(q)), (t + arrive_s + dwell_s, still(q))]
        t += arrive_s + dwell_s
    return segments


class Cell:
    """A robot on a script, a drawstring reading ``ANCHOR_MM + q1`` and a dial reading 0.25 mm,
    each overridable; ``run()`` runs a session on them and keeps its messages."""

    def __init__(
        self,
        tmp_path,
        clock: FakeClock,
        robot: Script,
        folder: SessionFolder | None = None,
        plan: Plan = PLAN,
    ):
        self.clock, self.plan = clock, plan
        self.robot = ScriptedDriver("robot", ROBOT_FIELDS, robot, clock)
        self.drawstring = ScriptedDriver(
            "drawstring", {"length_mm": Field("mm")}, self.length_from_pose, clock
        )
        self.dial = ScriptedDriver("dial", {"dial_mm": Field("mm")}, lambda t: {"dial_mm": 0.25}, clock)
        header = {"start_wall_s": T0_WALL, "station": {"time_scale": 1.0}}
        self.folder = folder or SessionFolder.create(tmp_path / "sess", header)
        self.messages: list[str] = []
        self.on_sample: Callable[[dict, Capture], None] = lambda row, cap: None
        self.on_message: Callable[[str], None] = lambda text: None
        self.on_tick: Callable[[], None] = lambda: None

    def length_from_pose(self, t: float) -> dict:
        return {"length_mm": ANCHOR_MM + self.robot.script(t)["q_deg"][0]}

    def session(self, listener: Listener | None = None) -> Session:
        drivers = {"robot": self.robot, "drawstring": self.drawstring, "dial": self.dial}
        devices = Devices(drivers, BACKOFF, sleep=self.clock.sleep)

        def message(text: str) -> None:
            self.messages.append(text)
            self.on_message(text)

        listener = listener or Listener(lambda row, cap: self.on_sample(row, cap), message, self.on_tick)
        return Session(
            self.folder, self.plan, devices, RULES, listener, clock=self.clock, sleep=self.clock.sleep
        )

    def run(self) -> State:
        return self.session().run()

    def targets(self) -> list[int]:
        return [int(r["target"]) for r in self.folder.rows]

    def said(self, start: str) -> bool:
        return any(m.startswith(start) for m in self.messages)


def stop_after_the_first_sample(cell: Cell) -> State:
    """Run a session on ``cell`` whose first stored sample requests a stop (as Ctrl-C would)."""
    session = cell.session()
    cell.on_sample = lambda row, cap: session.request_stop()
    return session.run()


def test_every_target_captured_once_with_its_readings(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    assert cell.run() is State.DONE
    assert cell.targets() == [0, 1, 2]
    assert [int(r["sample"]) for r in cell.folder.rows] == [0, 1, 2]
    for row, q in zip(cell.folder.rows, PLAN.q_deg, strict=True):
        assert float(row["length_mm"]) == pytest.approx(ANCHOR_MM + q[0])
        assert float(row["dial_mm"]) == pytest.approx(0.25)
        assert [float(row[f"q{i + 1}_deg"]) for i in range(6)] == pytest.approx(q)
    raw = cell.folder.raw_csv.read_text().splitlines()
    assert len(raw) == 1 + RULES.readings * len(PLAN)
    # each capture comes settle_s after the robot arrives (2.5 s walk per target, 0.5 s moving)
    late_s = np.array([float(r["t_s"]) for r in cell.folder.rows]) - [0.5, 3.0, 5.5] - RULES.settle_s
    assert np.all((late_s >= 0) & (late_s < 3 * RULES.poll_s))
    assert cell.messages[-1].startswith("done: all 3 targets measured; 3 samples")


def test_a_revisited_target_is_not_captured_twice(tmp_path, clock):
    q = PLAN.q_deg
    cell = Cell(tmp_path, clock, timeline(*walk([q[0], q[1], q[0], q[1], q[2]])))
    assert cell.run() is State.DONE
    assert cell.targets() == [0, 1, 2]


def test_resumed_session_captures_only_the_unfinished_targets(tmp_path, clock):
    first = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    assert stop_after_the_first_sample(first) is State.STOPPED
    assert first.targets() == [0]

    clock.now = 0.0  # a new process: the robot walks the whole plan again
    resumed = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)), SessionFolder.open(tmp_path / "sess"))
    assert resumed.run() is State.DONE
    assert resumed.targets() == [0, 1, 2]
    assert [int(r["sample"]) for r in SessionFolder.open(tmp_path / "sess").rows] == [0, 1, 2]


def test_a_pose_away_from_every_target_is_not_matched(tmp_path, clock):
    off = PLAN.q_deg[0] + [0, 0, 0, 0, 0, RULES.match_deg + 0.5]
    cell = Cell(tmp_path, clock, timeline((0.5, moving(off)), (1e9, still(off))))
    assert cell.run() is State.TIMED_OUT
    assert cell.folder.rows == []
    assert "settled only at finished targets or away from the plan" in cell.messages[-1]
    assert clock() == pytest.approx(RULES.target_timeout_s, abs=3 * RULES.poll_s)


def test_a_robot_that_never_settles_times_out_after_the_target_timeout(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline((1e9, moving(PLAN.q_deg[0]))))
    assert cell.run() is State.TIMED_OUT
    assert clock() == pytest.approx(RULES.target_timeout_s, abs=3 * RULES.poll_s)
    assert cell.messages[-1].startswith("timed out: no capture for 10 s: the robot never settled")
    assert cell.drawstring.reads == 0  # gates and captures wait for a settled robot


def test_robot_not_running_suspends_and_the_session_resumes(tmp_path, clock):
    q = PLAN.q_deg
    # still at target 0 but not yet settled when the controller leaves RUNNING (0.8 s .. 3 s)
    segments = [(0.5, moving(q[0])), (0.8, still(q[0])), (3.0, still(q[0], mode=5)), (5.0, still(q[0]))]
    cell = Cell(tmp_path, clock, timeline(*segments, *walk(q[1:], start_s=5.0)))
    assert cell.run() is State.DONE
    assert cell.said("suspended: robot not running (robot mode 5, 7 = RUNNING)")
    assert "resumed" in cell.messages
    late_s = float(cell.folder.rows[0]["t_s"]) - 3.0 - RULES.settle_s
    assert 0 <= late_s < SUSPENDED_POLL_S + 3 * RULES.poll_s
    assert cell.targets() == [0, 1, 2]


def test_slack_cable_suspends_until_the_drawstring_is_back_in_its_gate(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    cell.drawstring.script = lambda t: {"length_mm": 10.0} if t < 2.0 else cell.length_from_pose(t)
    assert cell.run() is State.DONE
    assert cell.said("suspended: drawstring reads 10.000 mm, outside 50..5000 mm: cable slack or jump")
    assert "resumed" in cell.messages
    assert float(cell.folder.rows[0]["t_s"]) >= 2.0  # nothing stored from the slack cable
    assert cell.targets() == [0, 1, 2]


def test_a_silent_dial_suspends_and_nothing_is_stored_until_it_answers(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    silent = DeviceTimeout("dial", "no reply within 0.2 s")
    cell.dial.script = lambda t: silent if 5.0 <= t < 7.0 else {"dial_mm": 0.25}  # at target 1
    assert cell.run() is State.DONE
    assert cell.said("suspended: dial not answering: unreachable after 2 attempts (no reply within 0.2 s)")
    assert "resumed" in cell.messages
    assert cell.targets() == [0, 1, 2]
    assert float(cell.folder.rows[1]["t_s"]) >= 7.0  # nothing stored while the dial was silent
    assert cell.dial.closes > 0 and cell.dial.opens == cell.dial.closes  # reconnected on each retry


def test_a_dial_silent_past_the_unreachable_limit_ends_the_session(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=1e9)))
    cell.dial.script = lambda t: DeviceTimeout("dial", "no reply within 0.2 s")
    with pytest.raises(DeviceError, match=r"dial not answering: .* \(silent for over 5 s; 0 samples kept\)"):
        cell.run()
    suspended_s = 0.5 + RULES.settle_s  # settled at target 0, the gate read the dial
    silent_for = clock() - suspended_s
    assert RULES.unreachable_s < silent_for < RULES.unreachable_s + SUSPENDED_POLL_S + 0.2


def test_a_transient_failure_is_retried_without_suspending(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    glitch = iter([DeviceTimeout("drawstring", "no reply")])
    cell.drawstring.script = lambda t: next(glitch, None) or cell.length_from_pose(t)
    assert cell.run() is State.DONE
    assert not cell.said("suspended")
    assert cell.drawstring.closes == 1 and cell.drawstring.opens == 1  # one reconnect ...
    late_s = float(cell.folder.rows[0]["t_s"]) - 0.5 - RULES.settle_s
    assert late_s >= BACKOFF.initial_s  # ... after the backoff, waited on the session's clock
    assert cell.targets() == [0, 1, 2]


def test_a_dial_out_of_range_suspends_as_a_gate(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    off_edge = DeviceReplyError("dial", "device error 'ERR3'", code="3")
    cell.dial.script = lambda t: off_edge if t < 2.0 else {"dial_mm": 0.25}
    assert cell.run() is State.DONE
    assert cell.said("suspended: dial out of range (device error 'ERR3')")
    assert cell.targets() == [0, 1, 2]


def test_a_jump_within_a_capture_rejects_it_and_the_target_is_captured_later(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    reads = iter(range(1_000_000))

    def jumpy(t: float) -> dict:
        value = cell.length_from_pose(t)
        if next(reads) == 1:  # the first capture round (read 0 was the gate)
            value["length_mm"] += 1.0
        return value

    cell.drawstring.script = jumpy
    session = cell.session()
    assert session.run() is State.DONE
    assert cell.said("capture at target 0 rejected: drawstring jumped (1.000 mm within the capture)")
    assert session.rejected == 1
    assert cell.targets() == [0, 1, 2]
    assert float(cell.folder.rows[0]["length_mm"]) == pytest.approx(ANCHOR_MM + PLAN.q_deg[0][0])


def test_a_stop_request_ends_the_session_after_the_sample_in_flight(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    assert stop_after_the_first_sample(cell) is State.STOPPED
    assert cell.targets() == [0]
    assert len(cell.folder.raw_csv.read_text().splitlines()) == 1 + RULES.readings
    assert cell.messages[-1].startswith("stopped: stopped on request; 1 samples")


def test_a_stop_request_while_suspended_ends_the_session(tmp_path, clock):
    q = PLAN.q_deg[0]
    cell = Cell(tmp_path, clock, timeline((0.5, moving(q)), (1e9, still(q, mode=5))))
    session = cell.session()
    cell.on_message = lambda text: text.startswith("suspended") and session.request_stop()
    assert session.run() is State.STOPPED
    assert "resumed" not in cell.messages
    assert cell.folder.rows == []


def test_a_fault_that_a_retry_clears_is_named_in_the_log(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    glitch = iter([CrcError("drawstring", "bad CRC in reply 01 03 04")])
    cell.drawstring.script = lambda t: next(glitch, None) or cell.length_from_pose(t)
    assert cell.run() is State.DONE
    assert "drawstring: bad CRC in reply 01 03 04; retrying" in cell.messages
    assert not cell.said("suspended")


def test_a_silent_device_is_named_once_not_at_every_reconnect_while_suspended(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    cell.dial.script = lambda t: DeviceTimeout("dial", "no reply") if 5.0 <= t < 7.0 else {"dial_mm": 0.25}
    assert cell.run() is State.DONE
    retries = [m for m in cell.messages if m.startswith("dial: no reply; retrying")]
    assert len(retries) == 1  # before the session suspended; its reconnects while waiting are not told
    assert cell.dial.reads > 10  # though it was asked again every poll


def test_a_cable_slackening_during_a_capture_rejects_it(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    reads = iter(range(1_000_000))

    def slackens(t: float) -> dict:
        # read 0 is the gate (taut); the cable comes off for the whole first capture (reads 1..3)
        return {"length_mm": 12.0} if 1 <= next(reads) <= RULES.readings else cell.length_from_pose(t)

    cell.drawstring.script = slackens
    assert cell.run() is State.DONE
    assert cell.said(
        "capture at target 0 rejected: drawstring read 12.000 mm, outside 50..5000 mm: cable slack or jump"
    )
    lengths = [float(r["length_mm"]) for r in cell.folder.rows]
    assert lengths == pytest.approx([ANCHOR_MM + q[0] for q in PLAN.q_deg])  # nothing slack stored


def test_each_condition_that_holds_a_suspension_is_named(tmp_path, clock):
    q = PLAN.q_deg
    # at target 0 the controller stops (0.8 .. 2 s) and the dial falls silent (1.5 .. 3 s)
    segments = [(0.5, moving(q[0])), (0.8, still(q[0])), (2.0, still(q[0], mode=5)), (6.0, still(q[0]))]
    cell = Cell(tmp_path, clock, timeline(*segments, *walk(q[1:], start_s=6.0)))
    cell.dial.script = lambda t: DeviceTimeout("dial", "no reply") if 1.5 <= t < 3.0 else {"dial_mm": 0.25}
    assert cell.run() is State.DONE
    suspended = [m for m in cell.messages if m.startswith("suspended")]
    assert suspended[0].startswith("suspended: robot not running")
    assert suspended[1].startswith("suspended: dial not answering")
    assert cell.targets() == [0, 1, 2]


def test_a_new_kind_of_failure_of_a_silent_device_is_named(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    silent, garbled = DeviceTimeout("dial", "no reply"), GarbledReply("dial", "unparseable reply b'#'")
    # at target 1 the dial falls silent, then answers garbage, then recovers
    cell.dial.script = lambda t: (
        silent if 5.0 <= t < 6.0 else garbled if 6.0 <= t < 7.0 else {"dial_mm": 0.25}
    )
    assert cell.run() is State.DONE
    suspended = [m for m in cell.messages if m.startswith("suspended")]
    assert suspended == [
        "suspended: dial not answering: unreachable after 2 attempts (no reply)",
        "suspended: dial not answering: unreachable after 2 attempts (unparseable reply b'#')",
    ]
    assert cell.targets() == [0, 1, 2]


def test_a_finish_request_ends_the_session_done_with_its_reason_and_targets_left(tmp_path, clock):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    session = cell.session()
    cell.on_sample = lambda row, cap: session.finish("accuracy reached")
    assert session.run() is State.DONE
    assert cell.targets() == [0]
    assert cell.messages[-1].startswith("done: accuracy reached; 1 samples")


def test_the_listener_ticks_at_every_checkpoint_also_while_suspended(tmp_path, clock):
    q = PLAN.q_deg[0]
    cell = Cell(
        tmp_path, clock, timeline((0.5, moving(q)), (3.0, still(q, mode=5)), *walk(PLAN.q_deg, start_s=3.0))
    )
    ticks = []
    cell.on_tick = lambda: ticks.append(clock())
    assert cell.run() is State.DONE
    suspended = [t for t in ticks if 0.5 < t < 3.0]
    assert len(suspended) >= (2.5 - RULES.settle_s) / SUSPENDED_POLL_S - 2  # each suspended poll
    assert np.max(np.diff(ticks)) < SUSPENDED_POLL_S + RULES.readings * 4 * READ_S + 0.01


def test_a_resumed_program_walking_many_finished_targets_does_not_time_out(tmp_path, clock):
    """The robot program restarts at its first target: it walks the measured ones (longer in all
    than the target timeout) before the unfinished one, which is then captured."""
    n = 12
    q = np.array([[10.0 + 5 * k, -20, 30, 0, 45, 0] for k in range(n)])
    plan = Plan.of(q, np.zeros(n, int))
    assert n * 2.5 > 2 * RULES.target_timeout_s
    first = Cell(tmp_path, clock, timeline(*walk(q[:-1])), plan=plan)
    session = first.session()
    first.on_sample = lambda row, cap: session.request_stop() if int(row["target"]) == n - 2 else None
    assert session.run() is State.STOPPED

    clock.now = 0.0
    resumed = Cell(tmp_path, clock, timeline(*walk(q)), SessionFolder.open(tmp_path / "sess"), plan)
    assert resumed.run() is State.DONE
    assert resumed.targets() == list(range(n))


def test_a_robot_parked_at_a_finished_target_still_times_out(tmp_path, clock):
    first = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    assert stop_after_the_first_sample(first) is State.STOPPED

    clock.now = 0.0
    q0 = PLAN.q_deg[0]
    robot = timeline((0.5, moving(q0)), (1e9, still(q0)))
    parked = Cell(tmp_path, clock, robot, SessionFolder.open(tmp_path / "sess"))
    assert parked.run() is State.TIMED_OUT
    assert "settled only at finished targets or away from the plan" in parked.messages[-1]


def test_a_robot_standing_off_the_edge_times_out_saying_so(tmp_path, clock):
    """The program ends at a target where the dial reads outside its gate (a nominal program on a
    real robot): the session does not wait for ever, and says why nothing is captured."""
    q = PLAN.q_deg
    cell = Cell(tmp_path, clock, timeline(*walk(q[:2]), (1e9, still(q[2]))))
    cell.dial.script = lambda t: {"dial_mm": 0.25 if t < 5.0 else -3.5}
    assert cell.run() is State.TIMED_OUT
    assert cell.targets() == [0, 1]
    assert cell.said("suspended: dial reads -3.500 mm, outside its gate")
    assert cell.messages[-1].startswith("timed out: no capture for 10 s: the dial reads outside its gate")
    assert (
        "correct the remaining targets (station calibrate, then station program the plan with --table"
        in cell.messages[-1]
    )
    assert clock() < 5.0 + RULES.target_timeout_s + 5.0


def test_a_robot_off_the_edge_is_told_the_remedy_its_session_knows(tmp_path, clock):
    """Where the targets are corrected in-session, the remedy is the listener's (run the program
    again), not the offline route."""
    q = PLAN.q_deg
    cell = Cell(tmp_path, clock, timeline(*walk(q[:1]), (1e9, still(q[1]))))
    cell.dial.script = lambda t: {"dial_mm": 0.25 if t < 2.0 else -3.5}
    listener = Listener(message=cell.messages.append, remedy=lambda: "run the robot program again")
    assert cell.session(listener).run() is State.TIMED_OUT
    assert cell.messages[-1].startswith("timed out: no capture for 10 s: the dial reads outside its gate")
    assert "(the tool off the edge): run the robot program again; 1 samples in" in cell.messages[-1]


def teleports_during_the_first_capture(cell: Cell, to_q, *, values=None) -> None:
    """From the first gate read of the drawstring on, the next ``readings + 1`` robot readings (the
    first capture's) are still at ``to_q`` (with ``values`` added): stale or wrong packages."""
    state = {"left": 0}
    script = cell.robot.script

    def length(t: float) -> dict:  # the sensor measures where the robot really is
        return {"length_mm": ANCHOR_MM + script(t)["q_deg"][0]}

    def robot(t: float) -> dict:
        if state["left"] > 0:
            state["left"] -= 1
            return {**still(to_q), **(values or {})}
        return script(t)

    def drawstring(t: float) -> dict:
        if state["left"] == 0 and not cell.folder.rows and not state.get("done"):
            state["left"], state["done"] = RULES.readings + 1, True
        return length(t)

    cell.robot.script, cell.drawstring.script = robot, drawstring


def stored_within_match(cell: Cell) -> bool:
    q = np.array([[float(r[f"q{i + 1}_deg"]) for i in range(6)] for r in cell.folder.rows])
    planned = cell.plan.q_deg[[int(r["target"]) for r in cell.folder.rows]]
    return bool(np.all(np.abs(q - planned).max(axis=1) <= RULES.match_deg))


def test_a_capture_whose_joints_are_not_at_its_target_is_rejected_and_taken_again(tmp_path, clock):
    """Issue 20: the settled joints matched target 0, the capture's own (identical, still) joints
    are at target 2's pose: nothing may be stored under target 0 from them."""
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    teleports_during_the_first_capture(cell, PLAN.q_deg[2])
    assert cell.run() is State.DONE
    assert cell.said(
        "capture at target 0 rejected: the robot left before the capture finished (joints up to 20.00 deg "
        "from the target, over 2 deg); taken again only if the robot settles there again: the robot "
        "program decides (one that walks the plan once moves on for good; the session's end says how to "
        "measure what is left)"
    )
    assert cell.targets() == [0, 1, 2]
    assert stored_within_match(cell)


def test_a_capture_of_late_robot_packages_is_rejected(tmp_path, clock):
    """The controller's packages of the first capture arrived 0.6 s late (a loaded station): the
    joints they carry are not the robot's while the sensors were read."""
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    teleports_during_the_first_capture(cell, PLAN.q_deg[0], values={"package_age_s": 0.6})
    assert cell.run() is State.DONE
    assert cell.said(
        "capture at target 0 rejected: the robot's data arrived 600 ms late (over the 500 ms window)"
    )
    assert cell.targets() == [0, 1, 2]


@pytest.mark.parametrize("device", ["drawstring", "robot"])
def test_a_capture_with_a_nan_reading_is_rejected_and_nothing_non_finite_is_stored(tmp_path, clock, device):
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    if device == "robot":
        teleports_during_the_first_capture(cell, [np.nan] * 6)
    else:
        reads = iter(range(1_000_000))
        length = cell.length_from_pose
        cell.drawstring.script = lambda t: {"length_mm": np.nan} if next(reads) % 7 == 3 else length(t)
    assert cell.run() is State.DONE
    what = "robot joints" if device == "robot" else "drawstring"
    assert cell.said(f"capture at target 0 rejected: the {what} gave no number (nan)")
    assert cell.targets() == [0, 1, 2]
    text = cell.folder.samples_csv.read_text() + cell.folder.raw_csv.read_text()
    assert "nan" not in text.lower() and "inf" not in text.lower()


def test_a_device_answering_only_with_errors_ends_the_session_after_the_unreachable_limit(tmp_path, clock):
    """Issue 21: a drawstring answering every read with a Modbus exception once was 'suspended /
    resumed' for ever; now it counts as failing and ``unreachable_s`` applies."""
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=1e9)))
    cell.drawstring.script = lambda t: DeviceReplyError(
        "drawstring", "Modbus exception code 2 reading length register 0..1", code="2"
    )
    with pytest.raises(DeviceError, match=r"exception code 2 .*\(answering only with errors for over 5 s"):
        cell.run()
    assert clock() < 0.5 + RULES.settle_s + RULES.unreachable_s + 1.0
    assert sum(m == "resumed" for m in cell.messages) == 0


def test_a_plan_target_the_program_never_visits_ends_the_session_naming_it(tmp_path, clock):
    """Issue 21: the robot cycles through targets 0 and 1 for ever and never goes to target 2:
    revisiting finished targets is no progress; the end names the target never reached."""
    q = PLAN.q_deg
    cell = Cell(tmp_path, clock, timeline(*walk([q[0], q[1]] * 200)))
    assert cell.run() is State.TIMED_OUT
    assert cell.targets() == [0, 1]
    assert cell.messages[-1].startswith("timed out: no capture for 10 s: the robot settled only at finished")
    assert "; never reached: target 2;" in cell.messages[-1]
    # the last capture at 3.0 + settle; then one cycle of new (finished) targets at most, then the timeout
    assert clock() < 3.0 + RULES.settle_s + 2 * 2.5 + RULES.target_timeout_s + 0.5


def test_suspensions_that_clear_and_recur_do_not_hold_the_session_for_ever(tmp_path, clock):
    """A slack cable suspends at each target the cycling robot settles at; its moving on clears it:
    the time between the suspensions counts toward the target timeout, the suspensions do not."""
    cell = Cell(tmp_path, clock, timeline(*walk(list(PLAN.q_deg) * 100)))
    cell.drawstring.script = lambda t: {"length_mm": 10.0}
    assert cell.run() is State.TIMED_OUT
    assert sum(m.startswith("suspended") for m in cell.messages) > 5
    assert cell.folder.rows == []


def test_a_stalled_stream_repeating_its_last_package_is_no_settle(tmp_path, clock):
    """The controller's packages stop advancing (its clock stands still) while the robot passes
    target 0: the repeated package looks still, but the robot never settles on it; the real dwell
    later is captured."""
    q = PLAN.q_deg

    def robot(t: float) -> dict:
        if 0.5 <= t < 3.0:  # stalled: the package of t = 0.5 over and over
            return {**still(q[0]), "controller_time_s": 0.5}
        return {**timeline((0.5, moving(q[0])), *walk(q, start_s=3.0))(t), "controller_time_s": t}

    cell = Cell(tmp_path, clock, robot)
    cell.robot.fields = {**ROBOT_FIELDS, "controller_time_s": Field("s")}
    cell.drawstring.script = lambda t: {"length_mm": ANCHOR_MM + q[0][0]}
    assert cell.run() is State.DONE
    assert float(cell.folder.rows[0]["t_s"]) >= 3.5  # not before the robot really arrived and rested


def test_a_stream_that_stalls_during_a_capture_rejects_it(tmp_path, clock):
    """From the first sensor read at target 0 on, the controller repeats one package for 1 s (its
    age grows): no robot package is sent after the sensors' last reading, so the robot's stillness
    is not known; rejected, and taken when the stream is back."""
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg, dwell_s=4.0)))
    robot, length, stall = cell.robot.script, cell.drawstring.script, {}

    def stalled(t: float) -> dict:
        if "from" in stall and t < stall["from"] + 1.0:
            return {**robot(t), "package_age_s": t - stall["from"]}
        return robot(t)

    def first_read_starts_the_stall(t: float) -> dict:
        stall.setdefault("from", t)
        return length(t)

    cell.robot.script, cell.drawstring.script = stalled, first_read_starts_the_stall
    assert cell.run() is State.DONE
    assert any("the robot's last data predate the sensors' last reading by" in m for m in cell.messages)
    assert cell.targets() == [0, 1, 2]
    assert float(cell.folder.rows[0]["t_s"]) > stall["from"] + 1.0


def test_a_stream_lagging_steadily_is_waited_for_not_rejected(tmp_path, clock):
    """Every package 30 ms late (a steady link delay the baseline did not absorb): the closing
    reading waits for the package sent after the sensors' last reading, and the capture stands."""
    cell = Cell(tmp_path, clock, timeline(*walk(PLAN.q_deg)))
    robot = cell.robot.script
    cell.robot.script = lambda t: {**robot(t), "package_age_s": 0.03}
    session = cell.session()
    assert session.run() is State.DONE
    assert session.rejected == 0
    assert cell.targets() == [0, 1, 2]


@pytest.mark.parametrize("remedy", [None, "run the robot program again"])
def test_captures_rejected_at_a_target_each_round_end_the_session_naming_it(tmp_path, clock, remedy):
    """The drawstring jumps in every capture at target 2 while the robot cycles: each attempt is
    progress until ``ATTEMPTS_PER_TARGET`` of them, then the session ends saying why, and what to do
    where the listener knows (the session's target channel corrects what is left)."""
    q = PLAN.q_deg
    cell = Cell(tmp_path, clock, timeline(*walk(list(q) * 100)))
    reads = iter(range(10**9))
    length = cell.length_from_pose

    def jumps_at_target_2(t: float) -> dict:
        value = length(t)
        at_2 = abs(value["length_mm"] - ANCHOR_MM - q[2][0]) < 1e-9
        return {"length_mm": value["length_mm"] + (next(reads) % 2) * at_2}

    cell.drawstring.script = jumps_at_target_2
    session = cell.session(Listener(message=cell.messages.append, remedy=lambda: remedy))
    assert session.run() is State.TIMED_OUT
    assert cell.targets() == [0, 1]
    assert cell.messages[-1].startswith("timed out: no capture for 10 s: every attempt at target 2 was")
    told = f"rejected or suspended (see above){f': {remedy}' if remedy else ''}; 2 samples in"
    assert cell.messages[-1].endswith(f"{told} {cell.folder.path}")
    assert session.rejected > ATTEMPTS_PER_TARGET


def segment_start(segments, t: float) -> float:
    """When the segment of ``timeline(*segments)`` holding at ``t`` began."""
    return max([0.0] + [until for until, _ in segments if until <= t])


@pytest.mark.parametrize("stamp", ["zero", "on change"])
def test_a_source_whose_clock_may_stand_still_is_timed_on_arrival_and_says_so_once(tmp_path, clock, stamp):
    """Issue 34, item 1: a ROS publisher stamping 0, or an OPC UA server stamping a value when it
    changes, holds its clock while the robot rests: timed on it, the rest never lasted."""
    segments = walk(PLAN.q_deg)
    script = timeline(*segments)

    def robot(t: float) -> dict:
        at = 0.0 if stamp == "zero" else segment_start(segments, t)
        return {**script(t), "controller_time_s": at}

    cell = Cell(tmp_path, clock, robot)
    cell.robot.fields = {**ROBOT_FIELDS, "controller_time_s": Field("s")}
    cell.robot.clock_may_stand_still = True
    assert cell.run() is State.DONE
    assert cell.targets() == [0, 1, 2]
    said = [m for m in cell.messages if "its clock stands still" in m]
    assert len(said) == 1 and said[0].startswith("robot: its clock stands still"), cell.messages
