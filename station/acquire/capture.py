"""What a session reads and when: the devices, the settle rule, the capture rule and its gates.

The capture rule (all times in real seconds here: the config's simulated seconds divided by the
shared ``time_scale``):

1. settled: every joint speed below ``settle_speed_deg_s`` and robot mode RUNNING for ``settle_s``;
2. gates at the settled pose: the drawstring inside ``length_range_mm`` (outside: cable slack or
   a jump), the dial inside ``dial_range_mm`` (the indicator touches the gauge edge) -- a failed
   gate suspends the session rather than recording garbage;
3. ``readings`` (K) rounds, each reading the robot, the drawstring and the dial once, all inside
   ``window_s``, and a closing robot reading; rejected if a reading fails its gate (the cable
   slackened after the check), the joints spread more than ``still_deg`` or a joint moved faster
   than the settle speed (the robot moved), or the drawstring spread more than ``jump_mm`` or the
   dial more than ``dial_stable_mm`` (a sensor jumped); also if a value is not a finite number, a
   robot reading lies farther than ``match_deg`` from the target (the robot left), a robot package
   is later than ``window_s`` or the closing one was sent before the sensors' last reading (the
   controller's stream fell behind; the closing reading waits up to ``window_s`` for a newer one);
4. the sample is the mean of the K rounds, with the standard deviation of each quantity and the
   timestamp of every reading.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.base import Backoff, DeviceReplyError, Driver, DriverError, Reading, call_with_reconnect
from station.config import SessionConfig

RUNNING = 7  # UR robot_mode RUNNING (RTDE guide)
JITTER_S = 0.005  # s: a robot package may be this much older than a reading taken as it arrived


@dataclass(frozen=True)
class Rules:
    """The capture rule in real seconds (see the module notes)."""

    settle_speed_deg_s: float
    settle_s: float
    readings: int
    window_s: float
    still_deg: float
    jump_mm: float
    dial_range_mm: tuple[float, float]
    dial_stable_mm: float
    length_range_mm: tuple[float, float]
    match_deg: float
    target_timeout_s: float
    unreachable_s: float
    time_scale: float = 1.0  # simulated s per real s: the config's times were divided by it

    @classmethod
    def from_config(cls, section: SessionConfig, time_scale: float) -> Rules:
        values = section.model_dump(exclude={"robot_model", "setup", "plan"})
        for key in ("settle_s", "window_s", "target_timeout_s"):
            values[key] /= time_scale
        return cls(**values, time_scale=time_scale)

    @property
    def poll_s(self) -> float:
        """Pause between robot polls while waiting to settle (at least 5 polls per settle time)."""
        return min(0.01, self.settle_s / 5)


class Suspend(Exception):
    """A condition that pauses the session until it clears; the message says which, ``cause``
    names the condition (the same while it lasts, whatever the readings)."""

    def __init__(
        self,
        reason: str,
        cause: str,
        device: str | None = None,
        error_reply: bool = False,
        reading: float | None = None,
    ):
        super().__init__(reason)
        self.cause = cause
        self.reading = reading  # the sensor's reading that failed its gate [mm], where there is one
        self.device = device  # set when the device stopped answering, or answers only with errors
        self.error_reply = error_reply  # it answers, with an error code


class Devices:
    """The session's opened drivers by name (``robot``, ``drawstring``, optional ``dial``).

    ``read(name)`` retries transient failures with a reconnect, waiting with ``sleep`` (s) between
    attempts and telling ``on_retry(error)`` of each failure retried; a device that stays silent or
    answers with an error code raises :class:`Suspend` naming it (a dial's error code is its gate:
    off the edge).
    """

    def __init__(
        self, drivers: dict[str, Driver], backoff: Backoff, sleep: Callable[[float], None] = time.sleep
    ):
        self.drivers = drivers
        self.backoff = backoff
        self.sleep = sleep
        self.on_retry: Callable[[DriverError], None] = lambda exc: None

    def open(self) -> None:
        for driver in self.drivers.values():
            driver.open()

    def close(self) -> None:
        for driver in self.drivers.values():
            driver.close()

    def read(self, name: str) -> Reading:
        driver = self.drivers[name]
        try:
            return call_with_reconnect(driver, driver.read, self.backoff, self.sleep, self.on_retry)
        except DeviceReplyError as exc:
            if name == "dial":
                raise Suspend(f"dial out of range ({exc.cause})", "dial out of range") from exc
            raise Suspend(str(exc), f"{name} error reply", device=name, error_reply=True) from exc
        except DriverError as exc:
            last = exc.__cause__ if isinstance(exc.__cause__, DriverError) else exc  # the last attempt's
            cause = f"{name} silent ({type(last).__name__})"  # a new kind of failure is a new cause
            raise Suspend(f"{name} not answering: {exc.cause}", cause, device=name) from exc


class Settle:
    """Whether the robot has been still for ``rules.settle_s``: mode RUNNING, every joint speed
    below ``settle_speed_deg_s`` and every joint within ``still_deg`` of where the still period
    began. ``ever`` says whether it settled at all since the last :meth:`reset`. The still period
    is timed on the controller's clock where the robot reports one (``controller_time_s``), and
    a package later than the capture window (``package_age_s``) breaks it: a stream that stalls
    repeats its last package, which is no evidence of a robot at rest. A source whose clock may
    stand still on fresh readings (``clock_may_stand_still``: a value stamped when it changes, or
    not at all) and holds it for ``settle_s`` is timed on the readings' arrival from then on, and
    ``note(text)`` says so once."""

    def __init__(
        self, rules: Rules, note: Callable[[str], None] = lambda text: None, clock_may_stand_still=False
    ):
        self.rules, self.note, self.clock_may_stand_still = rules, note, clock_may_stand_still
        self.ever = False
        self.on_arrival = False  # timed on the readings' arrival (the source's clock stands still)
        self._latest: tuple[float, float] | None = None  # the source's latest time, its arrival
        self.reset()

    def reset(self) -> None:
        self.since: tuple[float, float] | None = None  # (source, arrival) time the still period began
        self.q0: np.ndarray | None = None

    def update(self, robot: Reading) -> bool:
        t = self._times(robot)
        q = np.asarray(robot.values["q_deg"], float)
        speed = float(np.max(np.abs(robot.values["qd_deg_s"])))
        drift = 0.0 if self.q0 is None else float(np.max(np.abs(q - self.q0)))
        if (
            speed >= self.rules.settle_speed_deg_s
            or robot.values["robot_mode"] != RUNNING
            or drift > self.rules.still_deg
            or float(robot.values.get("package_age_s", 0.0)) > self.rules.window_s
        ):
            self.reset()
            return False
        if self.since is None:
            self.since, self.q0 = t, q
        clock = 1 if self.on_arrival else 0
        settled = t[clock] - self.since[clock] >= self.rules.settle_s
        self.ever |= settled
        return settled

    def _times(self, robot: Reading) -> tuple[float, float]:
        """The reading's time on the source's clock and on arrival [s]; turns to the arrival clock
        (saying so) once a source that may hold its clock has held it for ``settle_s``."""
        source, arrival = float(robot.values.get("controller_time_s", robot.t_monotonic)), robot.t_monotonic
        if self._latest is None or source > self._latest[0]:
            self._latest = (source, arrival)
        held = arrival - self._latest[1]
        if self.on_arrival or not self.clock_may_stand_still or held < self.rules.settle_s:
            return source, arrival
        self.on_arrival = True
        self.note(
            f"{robot.device}: its clock stands still (controller_time_s {source:g} over {held:.2f} s of "
            "readings): the robot's rest is timed on their arrival instead"
        )
        return source, arrival


def check_running(robot: Reading) -> None:
    mode = robot.values["robot_mode"]
    if mode != RUNNING:
        raise Suspend(f"robot not running (robot mode {mode}, {RUNNING} = RUNNING)", "robot not running")


def check_gates(devices: Devices, rules: Rules) -> None:
    """The sensor gates at a settled pose; a failed one raises :class:`Suspend`."""
    length = devices.read("drawstring").values["length_mm"]
    if why := length_outside(length, rules):
        raise Suspend(f"drawstring reads {why}", "drawstring gate")
    if "dial" in devices.drivers:
        dial = devices.read("dial").values["dial_mm"]
        if why := dial_outside(dial, rules):
            raise Suspend(f"dial reads {why}", "dial gate", reading=dial)


def length_outside(length_mm: float, rules: Rules) -> str | None:
    """Why a drawstring reading fails its gate (None: it passes)."""
    low, high = rules.length_range_mm
    if low <= length_mm <= high:
        return None
    return f"{length_mm:.3f} mm, outside {low:g}..{high:g} mm: cable slack or jump"


def dial_outside(dial_mm: float, rules: Rules) -> str | None:
    """Why a dial reading fails its gate (None: it passes)."""
    low, high = rules.dial_range_mm
    if low <= dial_mm <= high:
        return None
    return (
        f"{dial_mm:.3f} mm, outside its gate {low:g}..{high:g} mm: the tool is off the edge by that "
        "much (a nominal program lands off by the robot's error: correct the target or widen the gate)"
    )


@dataclass(frozen=True)
class Capture:
    """One accepted capture: means, standard deviations, window (s) and every raw round."""

    q_deg: np.ndarray
    length_mm: float
    dial_mm: float  # NaN without a dial
    q_spread_deg: float
    length_spread_mm: float
    dial_spread_mm: float
    window_s: float
    t_wall_s: float
    raw: list[dict]


class Rejected(Exception):
    """A capture that broke the rule; the message says how."""


def capture(devices: Devices, rules: Rules, target_q_deg=None) -> Capture:
    """K rounds of every device, checked against the rule (:class:`Rejected` if broken); with
    ``target_q_deg`` (deg) every robot reading must lie within ``match_deg`` of it."""
    has_dial = "dial" in devices.drivers
    rounds = []
    for _ in range(rules.readings):
        rounds.append([devices.read(n) for n in ("robot", "drawstring", "dial") if n != "dial" or has_dial])
    last_sensor_s = max(r.t_monotonic for r in rounds[-1][1:])
    closing = _closing(devices, rules, last_sensor_s)
    t_mono = [r.t_monotonic for rnd in rounds for r in rnd]
    window = max(t_mono) - min(t_mono)
    q = np.array([rnd[0].values["q_deg"] for rnd in rounds], float)
    robots = [rnd[0] for rnd in rounds] + [closing]
    length = np.array([rnd[1].values["length_mm"] for rnd in rounds], float)
    dial = (
        np.array([rnd[2].values["dial_mm"] for rnd in rounds], float)
        if has_dial
        else np.full(len(rounds), np.nan)
    )
    broken = _unusable(robots, length, dial if has_dial else None, rules, target_q_deg, last_sensor_s)
    if broken:  # the other checks compare numbers that are not the robot's now, or not numbers
        raise Rejected("; ".join(broken))
    qd = max(float(np.max(np.abs(r.values["qd_deg_s"]))) for r in robots)
    q_all = np.array([r.values["q_deg"] for r in robots], float)
    _check(rules, window, q_all, qd, length, dial)
    return Capture(
        q_deg=q.mean(axis=0),
        length_mm=float(length.mean()),
        dial_mm=float(dial.mean()),
        q_spread_deg=float(q.std(axis=0, ddof=1).max()),
        length_spread_mm=float(length.std(ddof=1)),
        dial_spread_mm=float(dial.std(ddof=1)) if has_dial else float("nan"),
        window_s=window,
        t_wall_s=rounds[0][0].t_wall,
        raw=[_raw_row(k, rnd) for k, rnd in enumerate(rounds)],
    )


def _closing(devices: Devices, rules: Rules, last_sensor_s: float) -> Reading:
    """The robot reading that brackets the sensors' last one (did the robot leave?): one whose
    package was sent after it (``package_age_s`` within ``JITTER_S`` of the time since), read
    again while the stream catches up, for ``window_s`` at most."""
    while True:
        closing = devices.read("robot")
        since = closing.t_monotonic - last_sensor_s
        if float(closing.values.get("package_age_s", 0.0)) <= since + JITTER_S or since > rules.window_s:
            return closing
        devices.sleep(JITTER_S / 4)


def _unusable(robots: list[Reading], length, dial, rules: Rules, target_q_deg, last_sensor_s) -> list[str]:
    """Why the readings of a capture cannot make a sample, in the operator's words: a value that
    is not a number, a robot package older than the capture window or a closing package sent
    before the sensors' last reading (``last_sensor_s``) (the controller's stream fell behind:
    ``package_age_s``, where the robot reports it), or the robot away from the target the capture
    is for (it left before the capture finished)."""
    broken = []
    q = np.array([r.values["q_deg"] for r in robots], float)
    qd = np.array([r.values["qd_deg_s"] for r in robots], float)
    for what, values in (
        ("robot joints", np.r_[q.ravel(), qd.ravel()]),
        ("drawstring", length),
        ("dial", dial),
    ):
        if values is not None and not np.all(np.isfinite(values)):
            broken.append(f"the {what} gave no number ({_first_bad(values)})")
    age = max((float(r.values.get("package_age_s", 0.0)) for r in robots), default=0.0)
    if age > rules.window_s:
        broken.append(
            f"the robot's data arrived {age * 1e3:.0f} ms late (over the {rules.window_s * 1e3:.0f} ms "
            "window): the controller's stream fell behind"
        )
    closing = robots[-1]
    if (
        early := float(closing.values.get("package_age_s", 0.0)) - (closing.t_monotonic - last_sensor_s)
    ) > JITTER_S:
        broken.append(
            f"the robot's last data predate the sensors' last reading by {early * 1e3:.0f} ms: "
            "the controller's stream fell behind"
        )
    if target_q_deg is not None and np.all(np.isfinite(q)):
        away = float(np.max(np.abs(q - np.asarray(target_q_deg, float))))
        if away > rules.match_deg:
            broken.append(
                f"the robot left before the capture finished (joints up to {away:.2f} deg from the "
                f"target, over {rules.match_deg:g} deg)"
            )
    return broken


def _first_bad(values) -> str:
    values = np.asarray(values, float)
    return str(values[~np.isfinite(values)][0])


def _check(rules: Rules, window, q, qd, length, dial) -> None:
    """Raise :class:`Rejected` naming every way the capture broke the rule."""
    span = lambda a: float(np.ptp(a, axis=0).max())  # noqa: E731
    broken = []
    if window > rules.window_s:
        broken.append(f"readings took {window * 1e3:.1f} ms, over the {rules.window_s * 1e3:.1f} ms window")
    if span(q) > rules.still_deg or qd >= rules.settle_speed_deg_s:
        broken.append(
            "the robot left before the capture finished, so it will be taken again "
            f"(joints spread {span(q):.4f} deg, speed up to {qd:.3f} deg/s)"
        )
    # the gates hold for every reading: a cable that slackens after the gate check is not a sample
    for value, outside, what in ((length, length_outside, "drawstring"), (dial, dial_outside, "dial")):
        why = next((w for v in value if np.isfinite(v) and (w := outside(float(v), rules))), None)
        if why:
            broken.append(f"{what} read {why}")
    if span(length) > rules.jump_mm:
        broken.append(f"drawstring jumped ({span(length):.3f} mm within the capture)")
    if np.all(np.isfinite(dial)) and span(dial) > rules.dial_stable_mm:
        broken.append(f"dial not stable ({span(dial):.4f} mm within the capture)")
    if broken:
        raise Rejected("; ".join(broken))


def _raw_row(k: int, rnd: list[Reading]) -> dict:
    robot, length = rnd[0], rnd[1]
    row = {"k": k, "t_robot_s": robot.t_wall, "qd_max_deg_s": float(np.max(np.abs(robot.values["qd_deg_s"])))}
    row.update({f"q{i + 1}_deg": float(v) for i, v in enumerate(robot.values["q_deg"])})
    row.update(t_length_s=length.t_wall, length_mm=float(length.values["length_mm"]))
    if len(rnd) > 2:
        row.update(t_dial_s=rnd[2].t_wall, dial_mm=float(rnd[2].values["dial_mm"]))
    return row
