"""A sampling session as a small state machine, in the manner of bluesky's run engine.

States: WAITING (for the robot to settle at an unfinished target) -> CAPTURING -> WAITING ...;
SUSPENDED while a suspender holds (robot not running, a sensor out of its gate, a device not
answering), back to WAITING by itself when it clears; and the ends DONE (every target measured),
STOPPED (stop requested: Ctrl-C), TIMED_OUT (no progress of any kind for ``target_timeout_s``: no
capture stored, no attempt at an unfinished target (a settle there, whatever its gates and capture
then find; a target's first ``ATTEMPTS_PER_TARGET`` count), and no finished plan target settled at
that the robot had not settled at since the last capture or attempt; time spent suspended does not
count, so suspensions that clear and recur do not hold the session for ever); DONE also when asked
to finish early (:meth:`Session.finish`: the running calibration reached its goal). A device that
stays silent or answers only with errors for ``unreachable_s`` while the session is suspended for
it ends the session (DeviceError).

The log names every fault: each suspension and each change of the condition holding it, and each
transient failure retried (``drawstring: bad CRC in reply ...; retrying``); of the reconnects to a
device the session is suspended for, only a failure of a new kind.

Checkpoints sit between captures and between polls: a stop or finish request is honoured there, so
the sample in flight is always stored whole, and the listener's ``tick`` runs there (work that
must never delay a capture looks in on its results there). A capture is assigned to the nearest
target of the plan (joint space, max |dq| within ``match_deg``) and stored under it only if every
robot reading of the capture is still there (else it is rejected and taken again); if that target
is finished already (the robot revisits it) nothing is captured, so a resumed session never
duplicates a target.

Time is read from the ``clock`` (s, monotonic) and waited with the ``sleep`` the session is given,
so the engine runs on a simulated clock in the tests; the devices' readings carry their own stamps.
"""

from __future__ import annotations

import collections
import enum
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.base import DriverError
from errors import DeviceError
from station.acquire.capture import (
    Capture,
    Devices,
    Rejected,
    Rules,
    Settle,
    Suspend,
    capture,
    check_gates,
    check_running,
)
from station.formats.plan import Plan
from station.formats.session_folder import SessionFolder

SUSPENDED_POLL_S = 0.1  # re-check a suspending condition this often
ATTEMPTS_PER_TARGET = 10  # settles at one unfinished target that still count as progress


def _listed(targets: list[int]) -> str:
    """Target ids for a message: the first ten, then how many more."""
    more = f" and {len(targets) - 10} more" if len(targets) > 10 else ""
    return ", ".join(map(str, targets[:10])) + more


OFF_EDGE = ("dial gate", "dial out of range")
"""Suspensions of a robot that stands where the dial reads outside its gate: no progress."""

AGAIN = (
    "taken again only if the robot settles there again: the robot program decides (one that walks "
    "the plan once moves on for good; the session's end says how to measure what is left)"
)
"""What becomes of a target whose capture was rejected: the program, not the station, decides."""


class OffEdge(Exception):
    """The robot stood where the dial reads outside its gate for the target timeout."""


OFF_EDGE_TIMEOUT = (
    "no capture for {s:g} s: the dial reads outside its gate where the robot stands (the tool off the "
    "edge): {remedy}"
)
OFFLINE_REMEDY = (
    "correct the remaining targets (station calibrate, then station program the plan with --table "
    "and --session) or widen [session] dial_range_mm"
)
"""What to do about targets the robot cannot bring onto the edge where nothing corrects them in-session."""


class State(enum.Enum):
    WAITING = "waiting"
    CAPTURING = "capturing"
    SUSPENDED = "suspended"
    DONE = "done"
    STOPPED = "stopped"
    TIMED_OUT = "timed out"


@dataclass
class Listener:
    """What a session reports: ``sample(row, capture)`` after each stored sample,
    ``message(text)`` on every state change worth telling the operator, ``tick()`` at every
    checkpoint (between polls, also while suspended), ``settled(index)`` when the robot has
    settled at plan row ``index`` (finished or not), before anything is captured there, and
    ``remedy()``: what to do about the targets left when the session times out, where the session's
    owner knows better than the offline route (None: it does not)."""

    sample: Callable[[dict, Capture], None] = lambda row, cap: None
    message: Callable[[str], None] = lambda text: None
    tick: Callable[[], None] = lambda: None
    settled: Callable[[int], None] = lambda index: None
    remedy: Callable[[], str | None] = lambda: None


class Session:
    """Run ``plan`` against ``devices`` into ``folder`` under the capture ``rules``; ``clock()``
    gives the time (s, monotonic) and ``sleep(s)`` waits."""

    def __init__(
        self,
        folder: SessionFolder,
        plan: Plan,
        devices: Devices,
        rules: Rules,
        listener: Listener | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ):
        self.folder, self.plan, self.devices, self.rules = folder, plan, devices, rules
        self.listener = listener or Listener()
        self.clock, self.sleep = clock, sleep
        self.state = State.WAITING
        self.pending = [i for i, t in enumerate(plan.target) if int(t) not in folder.finished_targets]
        stands_still = getattr(devices.drivers.get("robot"), "clock_may_stand_still", False)
        self.settle = Settle(rules, self.listener.message, stands_still)
        self.rejected = 0
        self._visited: set[int] = set()  # plan targets settled at since the last capture
        self._reached: set[int] = set()  # plan targets settled at in this run
        self._attempts: collections.Counter[int] = collections.Counter()  # settles at unfinished targets
        self._attempted = False  # the last poll was an attempt that counts as progress
        self._at: int | None = None  # the unfinished target this poll attempts
        self.off_edge: dict[int, float] = {}  # plan row -> the dial's reading that kept it (NaN: none)
        self._suspended_by: Suspend | None = None
        self._last_retry: dict[str, type] = {}  # the kind of failure last logged, by device
        devices.on_retry = self._retrying
        self._stop = False
        self._finish: str | None = None
        self._t0_wall = float(folder.header["start_wall_s"])

    def request_stop(self) -> None:
        """Stop at the next checkpoint (safe from a signal handler)."""
        self._stop = True

    @property
    def stop_requested(self) -> bool:
        return self._stop

    def finish(self, reason: str) -> None:
        """End as DONE at the next checkpoint, saying ``reason``, with targets left unmeasured."""
        self._finish = reason

    def run(self) -> State:
        """Until every target is measured, a stop or finish request, or the target timeout."""
        last_progress = self.clock()
        while self.pending:
            self.listener.tick()
            if self._stop:
                return self._end(State.STOPPED, "stopped on request")
            if self._finish is not None:
                return self._end(State.DONE, self._finish)
            self._attempted, self._at = False, None
            try:
                if self._step():
                    last_progress = self.clock()
                    self.settle.ever = False
            except Suspend as why:
                self._note_off_edge(why)
                since = self.clock()
                try:
                    self._suspended(why)
                except OffEdge:
                    waited = self.rules.target_timeout_s * self.rules.time_scale
                    text = OFF_EDGE_TIMEOUT.format(s=waited, remedy=self.listener.remedy() or OFFLINE_REMEDY)
                    return self._end(State.TIMED_OUT, text)
                self.settle.reset()
                # an attempt is progress; else waiting out a condition is not idling
                last_progress = self.clock() if self._attempted else last_progress + self.clock() - since
                continue
            if self.clock() - last_progress > self.rules.target_timeout_s:
                return self._end(State.TIMED_OUT, self._timeout_message())
            self.sleep(self.rules.poll_s)
        return self._end(State.DONE, f"all {len(self.plan)} targets measured")

    def _step(self) -> bool:
        """One poll: True on progress, a sample stored or the robot settled at a finished target
        it had not settled at since the last capture (a resumed program walking what was measured
        before; a program cycling through them again is no progress). Raises :class:`Suspend`."""
        robot = self.devices.read("robot")
        check_running(robot)
        if not self.settle.update(robot):
            return False
        index = self._match(np.asarray(robot.values["q_deg"]))
        if index is None:  # away from every target: a wrong joint convention, once it shows, is said
            away = getattr(self, "away", None)  # station.acquire.convention.AwaySettles, set by the runner
            if away is not None and (advice := away.settled(robot.values["q_deg"])):
                self.listener.message(advice)
            return False
        self._reached.add(index)
        self.listener.settled(index)
        if index not in self.pending:
            new = index not in self._visited
            self._visited.add(index)
            return new
        self._attempt(index)
        check_gates(self.devices, self.rules)
        self.state = State.CAPTURING
        try:
            cap = capture(self.devices, self.rules, self.plan.q_deg[index])
        except Rejected as why:
            self.rejected += 1
            target = int(self.plan.target[index])
            self.listener.message(f"capture at target {target} rejected: {why}; {AGAIN}")
            self.settle.reset()
            return self._attempted
        finally:
            self.state = State.WAITING
        self._store(index, cap)
        self._visited.clear()
        return True

    def _attempt(self, index: int) -> None:
        """Count a settle at unfinished target ``index``: progress for its first
        ``ATTEMPTS_PER_TARGET`` (the robot's next round through the plan may succeed)."""
        self._attempts[index] += 1
        self._at = index
        if self._attempts[index] <= ATTEMPTS_PER_TARGET:
            self._attempted = True
            self._visited.clear()

    def _note_off_edge(self, why: Suspend) -> None:
        """Keep what the dial read where it kept the attempted target off the edge."""
        if self._at is not None and why.cause in OFF_EDGE:
            self.off_edge[self._at] = float("nan") if why.reading is None else why.reading

    def off_edge_left(self) -> dict[int, float]:
        """Target id -> the dial's reading there (NaN: out of range), of the unfinished targets the
        dial kept off the edge."""
        return {int(self.plan.target[i]): v for i, v in self.off_edge.items() if i in self.pending}

    def _match(self, q_deg: np.ndarray) -> int | None:
        """Index of the plan target nearest to ``q_deg`` if within ``match_deg`` (finished or not)."""
        dist = np.max(np.abs(self.plan.q_deg - q_deg), axis=1)
        nearest = int(np.argmin(dist))
        return nearest if dist[nearest] <= self.rules.match_deg else None

    def _store(self, index: int, cap: Capture) -> None:
        row = {
            "sample": self.folder.next_sample,
            "target": int(self.plan.target[index]),
            "line": int(self.plan.line[index]),
            **{f"q{i + 1}_deg": float(v) for i, v in enumerate(cap.q_deg)},
            "length_mm": cap.length_mm,
            "dial_mm": "" if np.isnan(cap.dial_mm) else cap.dial_mm,
            "t_s": cap.t_wall_s - self._t0_wall,
            "q_spread_deg": cap.q_spread_deg,
            "length_spread_mm": cap.length_spread_mm,
            "dial_spread_mm": "" if np.isnan(cap.dial_spread_mm) else cap.dial_spread_mm,
            "window_s": cap.window_s,
            "t_wall_s": cap.t_wall_s,
        }
        self.folder.append(row, [{"sample": row["sample"], **r} for r in cap.raw])
        self.pending.remove(index)
        self.listener.sample(row, cap)

    def _suspended(self, first: Suspend) -> None:
        """Stay SUSPENDED, re-checking every ``SUSPENDED_POLL_S``, until the condition clears (or a
        stop request). A device silent, or answering only with errors, for longer than
        ``unreachable_s`` ends the session (DeviceError); a robot standing off the edge
        (``OFF_EDGE``) for ``target_timeout_s`` raises :class:`OffEdge`."""
        self.state = State.SUSPENDED
        self.listener.message(f"suspended: {first}")
        self._suspended_by = first
        why, silent_since = first, self.clock()
        off_since = silent_since  # since when the present condition holds
        while not self._stop and self._finish is None:
            self.sleep(SUSPENDED_POLL_S)
            self.listener.tick()
            try:
                self._check_cleared(why)
                break
            except Suspend as still:
                if still.cause != why.cause:  # another condition holds the session now: say which
                    self.listener.message(f"suspended: {still}")
                    off_since = self.clock()
                why = self._suspended_by = still
                if why.cause in OFF_EDGE and self.clock() - off_since > self.rules.target_timeout_s:
                    raise OffEdge from still
                silent_since = silent_since if still.device else self.clock()
                if self.clock() - silent_since > self.rules.unreachable_s:
                    how = "answering only with errors" if still.error_reply else "silent"
                    raise DeviceError(
                        f"{still} ({how} for over {self.rules.unreachable_s:g} s; "
                        f"{len(self.folder.rows)} samples kept)"
                    ) from still
        self.state = State.WAITING
        self._suspended_by = None
        self._last_retry.clear()
        if not self._stop and self._finish is None:
            self.listener.message("resumed")

    def _retrying(self, error: DriverError) -> None:
        """Name a transient device failure in the log; while the session waits for that device to
        answer again, only a failure of another kind (its reconnects repeat the same one every poll)."""
        waiting_for = self._suspended_by.device if self._suspended_by else None
        if error.device == waiting_for and type(error) is self._last_retry.get(error.device):
            return
        self._last_retry[error.device] = type(error)
        self.listener.message(f"{error}; retrying")

    def _check_cleared(self, why: Suspend) -> None:
        """Raise :class:`Suspend` unless ``why`` has cleared: the robot runs, the silent device
        answers, and, if the robot is settled, the sensor gates pass (a robot moving on clears them).
        The robot comes first: a controller stopped while a sensor is silent is told too."""
        robot = self.devices.read("robot")
        check_running(robot)
        if why.device not in (None, "robot"):
            self.devices.read(why.device)
        if self.settle.update(robot):
            check_gates(self.devices, self.rules)

    def _timeout_message(self) -> str:
        scale = self.rules.time_scale
        waited = self.rules.target_timeout_s * scale
        if not self.settle.ever:
            why = (
                f"the robot never settled (still means joint speeds below "
                f"{self.rules.settle_speed_deg_s:g} deg/s and joints within {self.rules.still_deg:g} deg "
                f"for {self.rules.settle_s * scale:g} s)"
            )
        elif tried := [int(self.plan.target[i]) for i in self.pending if self._attempts[i]]:
            why = (
                f"every attempt at target{'s' if len(tried) > 1 else ''} {_listed(tried)} was rejected or "
                "suspended (see above)"
            )
            if remedy := self.listener.remedy():
                why += f": {remedy}"
        else:
            why = "the robot settled only at finished targets or away from the plan"
            never = [int(self.plan.target[i]) for i in self.pending if i not in self._reached]
            if never:
                why += f"; never reached: target{'s' if len(never) > 1 else ''} {_listed(never)}"
            if (advice := getattr(getattr(self, "away", None), "advice", None)) is not None:
                why += f"; {advice}"
        return f"no capture for {waited:g} s: {why}"

    def _end(self, state: State, text: str) -> State:
        self.state = state
        self.listener.message(f"{state.value}: {text}; {len(self.folder.rows)} samples in {self.folder.path}")
        return state
