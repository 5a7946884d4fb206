"""Robot joint angles from a ROS ``sensor_msgs/JointState`` topic through rosbridge (``roslibpy``).

``roslibpy`` keeps the WebSocket to the bridge and calls back with every message; the driver keeps
the latest and its arrival time. ``read()`` gives the latest message's joints in ``joint_names``'
order (a name the message lacks: :class:`~drivers.base.DeviceReplyError` naming it), in degrees
(ROS: rad, rad/s); a message older than ``stale_s`` (the publisher stopped) raises
:class:`~drivers.base.DeviceTimeout`, a closed bridge :class:`~drivers.base.DeviceUnreachable`.
Without velocities the speed is the change between two messages over their stamps. JointState has
no controller mode: ``robot_mode`` reads RUNNING (7, as over RTDE) while messages arrive.

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
from collections.abc import Sequence

import roslibpy

from drivers.base import DeviceReplyError, DeviceTimeout, DeviceUnreachable, Driver, Field, Reading

logging.getLogger("roslibpy").setLevel(logging.CRITICAL)  # its reconnect chatter: the driver reports

JOINTS = 6
RUNNING = 7
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
        self._previous: tuple[float, tuple[float, ...]] | None = None
        self._arrived = threading.Event()

    @property
    def _where(self) -> str:
        return f"rosbridge ws://{self.host}:{self.port} {self.topic}"

    def open(self) -> None:
        """Connect to the bridge, subscribe, and wait for the first message."""
        self._latest, self._previous = None, None
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
        with self._lock:
            self._latest = (time.monotonic(), message)
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
        if self._ros is None:
            raise DeviceUnreachable(self.name, f"{self._where} not connected (open() first)")
        if not self._ros.is_connected:
            raise DeviceUnreachable(self.name, f"{self._where} connection lost")
        with self._lock:
            arrived, message = self._latest
        age = time.monotonic() - arrived
        if age > self.stale_s:
            raise DeviceTimeout(self.name, f"no new message on {self._where} for {age:.2f} s")
        names = message.get("name", [])
        missing = [n for n in self.joint_names if n not in names]
        if missing:
            raise DeviceReplyError(
                self.name,
                f"{self._where}: no joint {missing[0]!r} in the message (it names {names})",
                "NO_JOINT",
            )
        index = [names.index(n) for n in self.joint_names]
        stamp = message["header"]["stamp"]
        t = stamp.get("secs", stamp.get("sec", 0)) + stamp.get("nsecs", stamp.get("nanosec", 0)) * 1e-9
        q = tuple(math.degrees(message["position"][i]) for i in index)
        velocity = message.get("velocity") or []
        if len(velocity) == len(names):
            qd = tuple(math.degrees(velocity[i]) for i in index)
        elif self._previous is None or t <= self._previous[0]:
            qd = (math.inf,) * JOINTS  # unknown until a second message: not settled
        else:
            qd = tuple((a - b) / (t - self._previous[0]) for a, b in zip(q, self._previous[1], strict=True))
        if self._previous is None or t > self._previous[0]:
            self._previous = (t, q)
        values = {"q_deg": q, "qd_deg_s": qd, "robot_mode": RUNNING, "controller_time_s": t}
        return Reading.now(self.name, values, ROS_FIELDS)


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
