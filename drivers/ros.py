"""Robot joint angles from a ROS ``sensor_msgs/JointState`` topic through rosbridge (``roslibpy``).

``roslibpy`` keeps the WebSocket to the bridge and calls back with every message; the driver keeps
the latest and its arrival time, and the last ``KEPT`` of them for :meth:`RosJointSource.received`
(a sweep streams every message, not the one that happens to be latest when polled). ``read()``
gives the latest message's joints in ``joint_names``'
order (a name the message lacks: :class:`~drivers.base.DeviceReplyError` naming it), in degrees
(ROS: rad, rad/s); a message older than ``stale_s`` (the publisher stopped) raises
:class:`~drivers.base.DeviceTimeout`, a closed bridge :class:`~drivers.base.DeviceUnreachable`.
Without velocities the speed is the change between two messages over their stamps (over their
arrivals where the stamps do not advance: a stamp of 0 is legal). JointState has no controller
mode: ``robot_mode`` reads RUNNING (7, as over RTDE) while messages arrive. A message that is no
JointState (not an object; no list of names; no stamp; a position, or a velocity that is not empty,
other than one finite number per name; a joint beyond ``MAX_JOINT_DEG``) is a
:class:`~drivers.base.GarbledReply` saying what is wrong, retried as RTDE's garbage is.

The target channel (``target_topic``): the driver advertises that topic, latched, and publishes each
corrected target on it as a ``sensor_msgs/JointState``: ``name`` the joint names, ``position`` the
contact joints [rad], ``header.frame_id`` the target's id (as text). A measurement node reads the
latest message before it moves to a target and takes those joints if the id is that target's.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Sequence

import roslibpy

from drivers.base import (
    MAX_JOINT_DEG,
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    Driver,
    Field,
    GarbledReply,
    Reading,
    excerpt,
)

logging.getLogger("roslibpy").setLevel(logging.CRITICAL)  # its reconnect chatter: the driver reports

JOINTS = 6
RUNNING = 7
KEPT = 4096  # messages kept for received(): 40 s at a 100 Hz topic
JOINT_STATE = "sensor_msgs/JointState"
ROS_FIELDS = {
    "q_deg": Field("deg", (JOINTS,), "JointState position"),
    "qd_deg_s": Field("deg/s", (JOINTS,), "JointState velocity (or the change between messages)"),
    "robot_mode": Field("", (), "7 (RUNNING) while messages arrive"),
    "controller_time_s": Field("s", (), "the message's header stamp, s since the epoch"),
}


class RosJointSource(Driver):
    """Joints of ``topic`` (``sensor_msgs/JointState``) from the rosbridge at ``host:port``, the six
    ``joint_names`` in joint order; corrected targets published on ``target_topic`` (None: none)."""

    fields = ROS_FIELDS
    no_channel = "no [robot] target_topic"
    clock_may_stand_still = True  # header.stamp 0 is legal; a message is at most stale_s old

    def __init__(
        self,
        host: str,
        port: int,
        topic: str,
        joint_names: Sequence[str],
        *,
        timeout_s: float = 2.0,
        stale_s: float = 0.5,
        name: str = "robot",
        target_topic: str | None = None,
    ):
        self.name, self.host, self.port, self.topic = name, host, port, topic
        self.joint_names, self.timeout_s, self.stale_s = list(joint_names), timeout_s, stale_s
        self.target_topic = target_topic
        self._ros = self._topic = self._targets = None
        self._lock = threading.Lock()
        self._latest: tuple[float, dict] | None = None
        self._arrivals: deque[tuple[float, float, dict]] = deque(maxlen=KEPT)  # monotonic, wall, message
        self._previous: tuple[float, float, tuple, tuple] | None = None  # arrival, stamp, q, qd
        self._arrived = threading.Event()

    @property
    def _where(self) -> str:
        return f"rosbridge ws://{self.host}:{self.port} {self.topic}"

    def open(self) -> None:
        """Connect to the bridge (a connection still open closed first), subscribe, and wait for
        the first message."""
        self.close()
        self._latest, self._previous = None, None
        self._arrivals.clear()
        self._arrived.clear()
        ros = roslibpy.Ros(self.host, self.port)
        try:
            ros.run(self.timeout_s)
        except Exception as exc:  # noqa: BLE001 - roslibpy raises its own or twisted's errors
            raise DeviceUnreachable(self.name, f"cannot connect to {self._where}: {exc}") from exc
        self._ros = ros
        self._topic = roslibpy.Topic(ros, self.topic, JOINT_STATE)
        self._topic.subscribe(self._on_message)
        if not self._arrived.wait(self.timeout_s):
            raise DeviceTimeout(self.name, f"no message on {self._where} within {self.timeout_s} s")
        if self.target_topic:
            self._targets = RosTargets(self, roslibpy.Topic(ros, self.target_topic, JOINT_STATE, latch=True))

    def _on_message(self, message: dict) -> None:
        arrived = time.monotonic()
        with self._lock:
            self._latest = (arrived, message)
            self._arrivals.append((arrived, time.time(), message))
        self._arrived.set()

    def target_channel(self) -> RosTargets | None:
        return self._targets

    def close(self) -> None:
        ros, self._ros, self._topic, self._targets = self._ros, None, None, None
        try:  # closing the connection ends the subscription (an unsubscribe would race the close)
            if ros is not None:
                ros.close()
        except Exception:  # noqa: BLE001 - a bridge already gone: nothing left to close
            pass

    def read(self) -> Reading:
        self._check_connected()
        with self._lock:
            arrived, message = self._latest
        age = time.monotonic() - arrived
        if age > self.stale_s:
            raise DeviceTimeout(self.name, f"no new message on {self._where} for {age:.2f} s")
        return Reading.now(self.name, self._values(arrived, message), ROS_FIELDS)

    def received(self) -> list[Reading]:
        """The messages that arrived since the last call (at most ``KEPT``), each stamped at its
        arrival; a malformed one is a GarbledReply, as :meth:`read`'s (those before it are lost)."""
        self._check_connected()
        with self._lock:
            arrivals = list(self._arrivals)
            self._arrivals.clear()
        units = {name: field.units for name, field in ROS_FIELDS.items()}
        return [
            Reading(self.name, self._values(arrived, message), units, arrived, wall)
            for arrived, wall, message in arrivals
        ]

    def _check_connected(self) -> None:
        if self._ros is None:
            raise DeviceUnreachable(self.name, f"{self._where} not connected (open() first)")
        if not self._ros.is_connected:
            raise DeviceUnreachable(self.name, f"{self._where} connection lost")

    def _values(self, arrived: float, message) -> dict:
        """A message's fields (see ``ROS_FIELDS``), ``arrived`` [s, monotonic] its arrival."""
        t, q, velocity = self._parse(message)
        qd = velocity if velocity is not None else self._speed(arrived, t, q)
        return {"q_deg": q, "qd_deg_s": qd, "robot_mode": RUNNING, "controller_time_s": t}

    def _speed(self, arrived: float, t: float, q: tuple[float, ...]) -> tuple[float, ...]:
        """The joints' change [deg/s] since the message before, over the stamps or, where they do
        not advance, over the arrivals; the same message read again, its speed; inf until a second
        message (not settled)."""
        if self._previous is not None and self._previous[0] == arrived:
            return self._previous[3]
        if self._previous is None:
            qd = (math.inf,) * JOINTS
        else:
            before, t_before, q_before, _ = self._previous
            dt = t - t_before if t > t_before else arrived - before
            qd = tuple((a - b) / dt for a, b in zip(q, q_before, strict=True))
        self._previous = (arrived, t, q, qd)
        return qd

    def _parse(self, message) -> tuple[float, tuple[float, ...], tuple[float, ...] | None]:
        """A JointState's stamp [s], joints [deg] and velocities [deg/s] (None: it has none), in
        ``joint_names``' order; a malformed message is a GarbledReply saying what is wrong."""
        if not isinstance(message, dict):
            raise self._garbled(f"a {type(message).__name__}, not a JointState", message)
        index = self._index(message)
        t = _stamp(message.get("header"))
        if t is None:
            raise self._garbled("its header.stamp is no time", message)
        q = self._angles(message, index)
        if not message.get("velocity"):
            return t, q, None
        velocity = _numbers(message["velocity"], len(message["name"]))
        if velocity is None:
            raise self._garbled(f"its velocity is neither empty nor {len(message['name'])} numbers", message)
        return t, q, tuple(math.degrees(velocity[i]) for i in index)

    def _index(self, message: dict) -> list[int]:
        """Where each of ``joint_names`` is in the message (a name it lacks: DeviceReplyError)."""
        names = message.get("name")
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise self._garbled("its name is no list of joint names", message)
        missing = [n for n in self.joint_names if n not in names]
        if missing:
            raise DeviceReplyError(
                self.name,
                f"{self._where}: no joint {missing[0]!r} in the message (it names {excerpt(repr(names))})",
                "NO_JOINT",
            )
        return [names.index(n) for n in self.joint_names]

    def _angles(self, message: dict, index: list[int]) -> tuple[float, ...]:
        """The joints at ``index`` [deg], each within ``MAX_JOINT_DEG``."""
        position = _numbers(message.get("position"), len(message["name"]))
        if position is None:
            raise self._garbled(f"its position is not {len(message['name'])} numbers", message)
        q = tuple(math.degrees(position[i]) for i in index)
        far = next((k for k, v in enumerate(q) if abs(v) > MAX_JOINT_DEG), None)
        if far is not None:
            what = f"{self.joint_names[far]} at {q[far]:g} deg, not an angle within +-{MAX_JOINT_DEG:g} deg"
            raise self._garbled(what, message)
        return q

    def _garbled(self, what: str, message) -> GarbledReply:
        return GarbledReply(
            self.name,
            f"{self._where} sent a message that is no JointState: {what} ({excerpt(repr(message))})",
        )


def _numbers(values, n: int) -> list[float] | None:
    """``values`` if a list of ``n`` finite numbers (not booleans), else None."""
    if not isinstance(values, list) or len(values) != n:
        return None
    ok = all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in values)
    return [float(v) for v in values] if ok else None


def _stamp(header) -> float | None:
    """A header's stamp, s (ROS 1 ``secs``/``nsecs``, ROS 2 ``sec``/``nanosec``); None: none."""
    stamp = header.get("stamp") if isinstance(header, dict) else None
    if not isinstance(stamp, dict):
        return None
    parts = _numbers([stamp.get("secs", stamp.get("sec")), stamp.get("nsecs", stamp.get("nanosec"))], 2)
    return None if parts is None else parts[0] + parts[1] * 1e-9


class RosTargets:
    """The target channel of a :class:`RosJointSource`: its ``target_topic``, latched."""

    def __init__(self, source: RosJointSource, topic):
        self.source, self.topic = source, topic
        self.where = (
            f"ROS topic {topic.name} on rosbridge ws://{source.host}:{source.port} (sensor_msgs/JointState, "
            "header.frame_id: the target's id)"
        )
        topic.advertise()

    def write(self, target: int, q_deg) -> None:
        """Publish target ``target``'s joints ``q_deg`` (6,) [deg] (a lost bridge: DeviceUnreachable)."""
        ros = self.source._ros
        if ros is None or not ros.is_connected:
            raise DeviceUnreachable(self.source.name, f"{self.source._where}: connection lost")
        message = {
            "header": {"frame_id": str(int(target))},
            "name": list(self.source.joint_names),
            "position": [math.radians(float(v)) for v in q_deg],
            "velocity": [],
            "effort": [],
        }
        self.topic.publish(roslibpy.Message(message))
