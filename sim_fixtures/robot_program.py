"""A simulated robot program: the operator stand-in that walks the robot through the plan.

The program starts dwelling at target 0, then forever: move to the next target, dwell there, ...,
move from the last target back to target 0, dwell, and round again. ``hold=True`` keeps the robot
still at target 0 (dwelling) for good.

Motion profile of one move, from configuration ``A`` to ``B`` (degrees), step by step:

1. Each joint must travel ``|B_i - A_i|`` degrees. The joint with the longest way, ``L`` degrees,
   leads; every joint obeys the same speed limit ``v`` (deg/s) and acceleration limit ``a``
   (deg/s^2), so the leading joint is the one that needs the longest time.
2. The leading joint follows a trapezoid: it accelerates at ``a`` for ``t_a = v / a`` seconds,
   covering ``v^2 / (2 a)`` degrees, cruises at ``v``, and brakes at ``a`` for the last ``t_a``
   seconds. The move lasts ``T = L / v + v / a``. Example: 60 deg at v = 30 deg/s, a = 60 deg/s^2
   takes 0.5 s up to speed (7.5 deg), 1.5 s cruising (45 deg), 0.5 s braking (7.5 deg): 2.5 s.
3. When ``L < v^2 / a`` the joint never reaches ``v``: the trapezoid becomes a triangle with peak
   speed ``sqrt(L a)`` and ``T = 2 sqrt(L / a)``.
4. Synchronised: every joint covers the same fraction ``s(t) / L`` of its own way at every instant,
   so all joints start and arrive together and the tool moves smoothly. A joint with a shorter
   way is proportionally slower, so no joint exceeds ``v`` or ``a``.
5. On arrival the robot dwells ``dwell_s`` seconds with zero velocity: that is when the station
   captures.

Time: ``state(t_s)`` takes real seconds since the program started; the program runs on simulated
time ``t_s * time_scale`` (``time_scale > 1`` plays the session faster). Speeds and accelerations
above, and the velocities reported, are per simulated second, as the controller would report them.

Corrected targets (``retarget``): a program a station hands corrected targets (UR: RTDE input
registers; OPC UA: writable nodes; ``sim_fixtures.target_channel``) asks, as it starts its move to
target k, what the channel holds; corrected joints for k replace the target from then on (the
move to it, and every later visit), so the joints the program reports are where the corrected
command really takes the robot. Asked once per target, on the first cycle. A program run once
(``once``) waits for play at ``home_deg`` (off the plan: target 0's joints with joint 2 lifted by
``HOME_LIFT_DEG``), asks for target 0 too as it starts and moves there first, to the corrected
joints if the channel holds them (the schedule runs that much later).

Faults for tests (:class:`RobotFault`, windows in simulated seconds): a robot mode other than
RUNNING (7) pauses the program (the joints stand still, as after a protective stop) and the
program resumes where it was when the window ends; ``jitter_deg`` adds Gaussian noise of that
standard deviation to every joint reading, so the robot never looks settled.
"""

from __future__ import annotations

import bisect
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

HOME_LIFT_DEG = 10.0
"""Where a program run once waits for play: joint 2 this far from target 0 (beyond a session's
``match_deg``, so the station does not take it for a target)."""

#: UR ``robot_mode`` values (RTDE guide): the program runs only in RUNNING.
POWER_OFF = 3
IDLE = 5
RUNNING = 7


@dataclass(frozen=True)
class RobotFault:
    """From ``start_s`` to ``end_s`` (simulated s) the robot reports ``robot_mode`` and its joint
    readings carry Gaussian noise of standard deviation ``jitter_deg``."""

    start_s: float
    end_s: float
    robot_mode: int = RUNNING
    jitter_deg: float = 0.0

    def __post_init__(self):
        if not self.end_s > self.start_s:
            raise ValueError(f"RobotFault needs end_s > start_s, got {self.start_s}..{self.end_s}")
        if self.jitter_deg < 0:
            raise ValueError(f"RobotFault.jitter_deg must be >= 0, got {self.jitter_deg}")

    def pauses(self) -> bool:
        """Whether the program stands still during the window."""
        return self.robot_mode != RUNNING


@dataclass(frozen=True)
class RobotState:
    """The robot at one instant: joints (deg), joint velocities (deg per simulated s), UR robot
    mode, the target it is at or moving to, whether it is dwelling there, and the TCP's speed along
    a gauge edge it sweeps (mm per simulated s; 0 off the edge: ``sim_fixtures.sweep_program``)."""

    q_deg: np.ndarray
    qd_deg_s: np.ndarray
    robot_mode: int
    target_index: int
    dwelling: bool
    speed_mm_s: float = 0.0


@dataclass(frozen=True)
class _Segment:
    """One piece of the cycle: a dwell at ``to`` or a move ``frm -> to``, from ``start_s``."""

    start_s: float
    duration_s: float
    frm: int
    to: int
    dwell: bool


def trapezoid(length_deg: float, t_s: float, speed: float, accel: float) -> tuple[float, float]:
    """Distance (deg) and speed (deg/s) of the leading joint ``t_s`` into a move of
    ``length_deg``, under the speed and acceleration limits (steps 2-3 of the module notes)."""
    if length_deg <= 0.0:
        return 0.0, 0.0
    t_acc = speed / accel
    if length_deg < speed * t_acc:  # triangle: never reaches cruise speed
        t_acc = np.sqrt(length_deg / accel)
        speed = accel * t_acc
    duration = length_deg / speed + t_acc
    t = min(max(t_s, 0.0), duration)
    if t < t_acc:  # speeding up
        return 0.5 * accel * t**2, accel * t
    if t > duration - t_acc:  # braking
        left = duration - t
        return length_deg - 0.5 * accel * left**2, accel * left
    return 0.5 * accel * t_acc**2 + speed * (t - t_acc), speed  # cruising


def move_duration(length_deg: float, speed: float, accel: float) -> float:
    """Seconds a move of ``length_deg`` (leading joint) takes: ``L/v + v/a``, or ``2 sqrt(L/a)``
    when too short to reach ``v``."""
    if length_deg <= 0.0:
        return 0.0
    if length_deg < speed**2 / accel:
        return 2.0 * np.sqrt(length_deg / accel)
    return length_deg / speed + speed / accel


class SimRobot:
    """The program: targets (M, 6) in degrees, visited in order, cyclically.

    ``speed_deg_s`` / ``accel_deg_s2`` bound every joint, ``dwell_s`` is the stay at each target
    (simulated s); ``once``: the program waits at home (see the module notes) until it starts, runs
    one cycle and stands at target 0 after it. ``rng`` (a
    seeded ``numpy.random.Generator``) is needed only for jitter faults. ``retarget(k, prog_s)``:
    the joints [deg] target k really takes if the program moves to a corrected target when its
    move to k starts at program time ``prog_s`` [simulated s], else None (see the module notes).
    """

    def __init__(
        self,
        targets_deg,
        *,
        speed_deg_s: float,
        accel_deg_s2: float,
        dwell_s: float,
        hold: bool = False,
        time_scale: float = 1.0,
        faults: Sequence[RobotFault] = (),
        rng: np.random.Generator | None = None,
        once: bool = False,
        retarget: Callable[[int, float], np.ndarray | None] | None = None,
    ):
        targets = np.array(targets_deg, dtype=float)  # a copy: corrected targets replace its rows
        if targets.ndim != 2 or targets.shape[1] != 6 or len(targets) == 0:
            raise ValueError(f"targets_deg must have shape (M, 6) with M >= 1, got {targets.shape}")
        for name, value in (
            ("speed_deg_s", speed_deg_s),
            ("accel_deg_s2", accel_deg_s2),
            ("time_scale", time_scale),
        ):
            if not value > 0:
                raise ValueError(f"{name} must be > 0, got {value}")
        if dwell_s < 0:
            raise ValueError(f"dwell_s must be >= 0, got {dwell_s}")
        if any(f.jitter_deg > 0 for f in faults) and rng is None:
            raise ValueError("a jitter fault needs rng, a seeded numpy.random.Generator")
        self.targets_deg = targets
        self.speed_deg_s = float(speed_deg_s)
        self.accel_deg_s2 = float(accel_deg_s2)
        self.dwell_s = float(dwell_s)
        self.hold = bool(hold)
        self.once = bool(once)
        self.time_scale = float(time_scale)
        self.faults = tuple(faults)
        self.rng = rng
        self.retarget = retarget
        self._asked = 1  # the next target whose move start asks ``retarget`` (the program starts at 0)
        self._lead_s: float | None = None  # a once-program's first move (home to target 0) [simulated s]
        self.home_deg = targets[0] + HOME_LIFT_DEG * np.eye(6)[1]
        self._lock = threading.Lock()
        self._reschedule()

    def __getstate__(self) -> dict:  # a spawned RTDE server gets a copy: locks do not travel
        return {k: v for k, v in self.__dict__.items() if k != "_lock"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _lock=threading.Lock())

    def _reschedule(self) -> None:
        self._segments = self._schedule()
        self._starts = [s.start_s for s in self._segments]
        last = self._segments[-1]
        self.cycle_s = last.start_s + last.duration_s

    def _schedule(self) -> list[_Segment]:
        """Dwell at 0, move 0->1, dwell at 1, ..., move (M-1)->0: one cycle."""
        segments, t = [], 0.0
        m = len(self.targets_deg)
        for k in range(m):
            nxt = (k + 1) % m
            length = float(np.max(np.abs(self.targets_deg[nxt] - self.targets_deg[k])))
            move = move_duration(length, self.speed_deg_s, self.accel_deg_s2)
            segments.append(_Segment(t, self.dwell_s, k, k, dwell=True))
            segments.append(_Segment(t + self.dwell_s, move, k, nxt, dwell=False))
            t += self.dwell_s + move
        return segments

    def program_time(self, sim_s: float) -> float:
        """Simulated seconds the program has run by ``sim_s``: pausing fault windows excluded."""
        paused = sum(max(0.0, min(sim_s, f.end_s) - f.start_s) for f in self.faults if f.pauses())
        return sim_s - paused

    def state(self, t_s: float) -> RobotState:
        """Where the robot is ``t_s`` real seconds after the program started."""
        sim_s = t_s * self.time_scale
        active = [f for f in self.faults if f.start_s <= sim_s < f.end_s]
        mode = next((f.robot_mode for f in active if f.pauses()), RUNNING)
        q, qd, index, dwelling = self._program_state(self.program_time(sim_s))
        if any(f.pauses() for f in active):
            qd = np.zeros(6)
        jitter = max((f.jitter_deg for f in active), default=0.0)
        if jitter > 0:
            q = q + self.rng.normal(0.0, jitter, 6)
        return RobotState(q, qd, mode, index, dwelling)

    def _program_state(self, prog_s: float) -> tuple[np.ndarray, np.ndarray, int, bool]:
        """Joints, joint speeds, target index and dwelling flag at program time ``prog_s``."""
        with self._lock:
            if not self.once or self.hold:
                self._corrections(prog_s)
                return self._walk(prog_s)
            if prog_s < 0:  # waiting for play
                return self.home_deg.copy(), np.zeros(6), 0, True
            lead_s = self._first_move()
            if prog_s < lead_s:
                return self._lead_state(prog_s)
            self._corrections(prog_s - lead_s, lead_s)
            return self._walk(prog_s - lead_s)

    def _first_move(self) -> float:
        """A program run once starts with a move from home to target 0, asking for its correction
        as it starts: that move's duration [simulated s]."""
        if self._lead_s is None:
            q = None if self.retarget is None else self.retarget(0, 0.0)
            if q is not None:
                self.targets_deg[0] = q
                self._reschedule()
            length = float(np.max(np.abs(self.targets_deg[0] - self.home_deg)))
            self._lead_s = move_duration(length, self.speed_deg_s, self.accel_deg_s2)
        return self._lead_s

    def _lead_state(self, prog_s: float) -> tuple[np.ndarray, np.ndarray, int, bool]:
        """On the first move, from home to target 0."""
        way = self.targets_deg[0] - self.home_deg
        length = float(np.max(np.abs(way)))
        s, sd = trapezoid(length, prog_s, self.speed_deg_s, self.accel_deg_s2)
        return self.home_deg + way * (s / length), way * (sd / length), 0, False

    def _corrections(self, prog_s: float, lead_s: float = 0.0) -> None:
        """Ask ``retarget`` about every first-cycle move that has started by ``prog_s`` (schedule
        time; the program's is ``lead_s`` later), in order; a corrected target changes the schedule
        from its move on (the moves before keep their times)."""
        if self.retarget is None or self.hold:
            return
        while self._asked < len(self.targets_deg) and self._starts[2 * self._asked - 1] <= prog_s:
            k = self._asked
            q = self.retarget(k, self._starts[2 * k - 1] + lead_s)
            if q is not None:
                self.targets_deg[k] = q
                self._reschedule()
            self._asked += 1

    def _walk(self, prog_s: float) -> tuple[np.ndarray, np.ndarray, int, bool]:
        if self.hold or self.cycle_s == 0.0 or prog_s < 0:  # before the program starts: at target 0
            return self.targets_deg[0].copy(), np.zeros(6), 0, True
        if self.once and prog_s >= self.cycle_s:  # a program run once ends back at target 0
            return self.targets_deg[0].copy(), np.zeros(6), 0, True
        tau = prog_s % self.cycle_s
        seg = self._segments[bisect.bisect_right(self._starts, tau) - 1]
        if seg.dwell:
            return self.targets_deg[seg.to].copy(), np.zeros(6), seg.to, True
        a, b = self.targets_deg[seg.frm], self.targets_deg[seg.to]
        way = b - a
        length = float(np.max(np.abs(way)))
        s, sd = trapezoid(length, tau - seg.start_s, self.speed_deg_s, self.accel_deg_s2)
        return a + way * (s / length), way * (sd / length), seg.to, False
