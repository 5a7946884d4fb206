"""Robot joint angles from a controller's OPC UA server (``asyncua``'s synchronous client).

A controller that follows the OPC UA Robotics companion specification (OPC 40010-1) publishes each
axis of its motion device under ``DeviceSet/<MotionDevice>/Axes/<Axis>/ParameterSet`` with
``ActualPosition`` (degrees for a rotary axis) and ``ActualSpeed`` (deg/s); the node ids are the
server's own, so the config names them (six, joint 1 first). Without speed nodes the speed is the
change of the positions between two reads over the time between them.

Corrected targets (:meth:`OpcUaJointSource.target_channel`): the companion specification has no
inputs for a running program, so a controller program or gateway that corrects targets offers
writable nodes of its own, named in the config: six joint positions (``target_nodes``, ``unit``)
and an Int32 index (``target_index_node``), written in one Write request, the positions first and
the index last (the program takes the positions once the index names its next target). Nodes the
server lacks, or will not let us write: no channel (``target_channel()`` None, ``no_channel`` why).

Subscription (``subscription_ms`` > 0, for a sweep: the joints at the controller's own rate, each
sample stamped by it): the position (and speed) nodes are monitored with a queue, the server
publishing every ``subscription_ms``; :meth:`OpcUaJointSource.received` assembles the changes into
readings, one per source timestamp, each axis not in it held at its last value (a server may stamp
its axes apart), the newest timestamp held back until a later one shows it whole (or two
publishing intervals pass). Each sample is asked for even where its value did not change (the
trigger StatusValueTimestamp): a server that ignores it sends nothing while the robot stands still,
so the link is also checked by a read every ``timeout_s`` (its errors as :meth:`read`'s).

The companion specification has no single "program running" flag, so ``robot_mode`` reads RUNNING
(7, as over RTDE) while the server answers; a stopped controller shows as joints that stand still.
Freshness: every read asks the server (a read, not a subscription), so a value is as old as the
round trip; a server that stops answering raises :class:`~drivers.base.DeviceTimeout` after the
client's ``timeout_s``, a lost connection :class:`~drivers.base.DeviceUnreachable`. asyncua's own
log (its tracebacks of a teardown that a stalled server does not answer) is silenced when a client
opens: the driver's errors say what failed.

Values: a node holds a number of a numeric type (a Boolean, a String or an array:
:class:`~drivers.base.DeviceReplyError`, the node is no axis's); a value that is not finite, or an
angle beyond ``MAX_JOINT_DEG``, is a :class:`~drivers.base.GarbledReply`, retried as RTDE's.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Sequence

from asyncua import ua
from asyncua.sync import Client, ThreadLoopNotRunning

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

JOINTS = 6
RUNNING = 7  # reported while the server answers (see the module notes)

OPCUA_FIELDS = {
    "q_deg": Field("deg", (JOINTS,), "axes' ActualPosition"),
    "qd_deg_s": Field("deg/s", (JOINTS,), "axes' ActualSpeed (or the change between reads)"),
    "robot_mode": Field("", (), "7 (RUNNING) while the server answers"),
    "controller_time_s": Field("s", (), "the server's source timestamp of joint 1, s since the epoch"),
}
UNIT_TO_DEG = {"deg": 1.0, "rad": math.degrees(1.0)}
QUEUE = 256  # values the server queues per node between publishes (2.5 s of a 100 Hz controller)
KEPT = 8 * 4096  # changes kept for received() (6 or 12 per sample)
NUMBERS = {
    getattr(ua.VariantType, name)
    for name in ("SByte", "Byte", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Float", "Double")
}


class OpcUaJointSource(Driver):
    """Joints from the OPC UA server at ``url`` (``opc.tcp://host:port``): ``position_nodes`` (six
    node ids, joint 1 first) in ``unit`` (``deg`` or ``rad``), optional ``speed_nodes`` (six, the
    same unit per second)."""

    fields = OPCUA_FIELDS
    clock_may_stand_still = True  # a SourceTimestamp may be when the value last changed (Part 4)

    def __init__(
        self,
        url: str,
        position_nodes: Sequence[str],
        speed_nodes: Sequence[str] | None = None,
        *,
        unit: str = "deg",
        timeout_s: float = 1.0,
        name: str = "robot",
        target_nodes: Sequence[str] | None = None,
        target_index_node: str | None = None,
        subscription_ms: float = 0.0,
    ):
        if len(position_nodes) != JOINTS or (speed_nodes is not None and len(speed_nodes) != JOINTS):
            raise ValueError(f"OPC UA joints need {JOINTS} position (and speed) node ids")
        self.name, self.url, self.unit, self.timeout_s = name, url, unit, timeout_s
        self.node_ids = [*position_nodes, *(speed_nodes or ())]
        self._speeds = speed_nodes is not None
        self._client: Client | None = None
        self._nodes = []
        self._last: tuple[float, tuple[float, ...]] | None = None
        self.target_ids = (
            None if not (target_nodes and target_index_node) else [*target_nodes, target_index_node]
        )
        self._targets: OpcUaTargets | None = None
        self.no_channel = "no target nodes configured" if self.target_ids is None else "not opened"
        self.subscription_ms = subscription_ms
        self._changes: deque[tuple[int, ua.DataValue, float, float]] = deque(maxlen=KEPT)
        self._lock = threading.Lock()
        self._held: dict[int, float] = {}  # node index -> its last value (the subscription's readings)
        self._pending: list[tuple[int, ua.DataValue, float, float]] = []  # the newest timestamp's
        self._pushed: tuple[float, tuple] | None = None  # the last subscribed reading's (stamp, q)
        self._checked = 0.0  # when the subscribed link was last checked by a read [s, monotonic]

    def open(self) -> None:
        """Connect and read every node once (a node id the server lacks: DeviceReplyError naming it);
        a client still open is closed first (its thread would outlive the process's work)."""
        self.close()
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # module notes
        client = Client(self.url, timeout=self.timeout_s, sync_wrapper_timeout=self.timeout_s + 1.0)
        try:
            client.connect()
        except (asyncio.TimeoutError, TimeoutError) as exc:
            client.tloop.stop()
            raise DeviceTimeout(self.name, self._silent) from exc
        except (OSError, ua.UaError) as exc:
            client.tloop.stop()
            raise DeviceUnreachable(self.name, f"cannot connect to OPC UA {self.url}: {_why(exc)}") from exc
        self._client, self._last = client, None
        self._nodes = [client.get_node(n) for n in self.node_ids]
        self._read_values()
        self._targets = self._find_targets()
        if self.subscription_ms > 0:
            self._subscribe()

    def _subscribe(self) -> None:
        """Monitor every node (module notes); the server's refusal is a DeviceReplyError."""
        with self._lock:
            self._changes.clear()
        self._held, self._pending, self._pushed, self._checked = {}, [], None, time.monotonic()
        params = ua.CreateSubscriptionParameters(
            RequestedPublishingInterval=self.subscription_ms,
            RequestedLifetimeCount=10_000,
            RequestedMaxKeepAliveCount=max(1, int(1000 * self.timeout_s / self.subscription_ms)),
            PublishingEnabled=True,
        )
        try:
            sub = self._client.create_subscription(params, _Changes(self))
            codes = sub.create_monitored_items([_every_sample(node, k) for k, node in enumerate(self._nodes)])
        except (asyncio.TimeoutError, TimeoutError) as exc:
            raise DeviceTimeout(self.name, self._silent) from exc
        except (OSError, ConnectionError, ThreadLoopNotRunning, ua.UaError) as exc:
            raise DeviceReplyError(
                self.name, f"OPC UA {self.url}: no subscription: {_why(exc)}", "SUBSCRIPTION"
            ) from exc
        bad = [(n, c) for n, c in zip(self.node_ids, codes, strict=True) if isinstance(c, ua.StatusCode)]
        if bad:
            raise DeviceReplyError(
                self.name,
                f"OPC UA {self.url}: cannot monitor node {bad[0][0]}: {bad[0][1].name}",
                bad[0][1].name,
            )

    def _changed(self, node: int, value: ua.DataValue) -> None:
        """A node's new value, from the subscription's thread."""
        with self._lock:
            self._changes.append((node, value, time.monotonic(), time.time()))

    @property
    def _silent(self) -> str:
        return f"OPC UA {self.url} did not answer within {self.timeout_s:g} s"

    def target_channel(self) -> OpcUaTargets | None:
        return self._targets

    def _find_targets(self) -> OpcUaTargets | None:
        """The target nodes, if the server has every one and lets us write them (``no_channel``:
        why not)."""
        if self.target_ids is None:
            return None
        params = ua.ReadParameters()
        for node_id in self.target_ids:
            for attr in (ua.AttributeIds.Value, ua.AttributeIds.UserAccessLevel):
                rv = ua.ReadValueId()
                rv.NodeId, rv.AttributeId = ua.NodeId.from_string(node_id), attr
                params.NodesToRead.append(rv)
        results = self._client.tloop.post(self._client.aio_obj.uaclient.read(params))
        for k, node_id in enumerate(self.target_ids):
            value, access = results[2 * k], results[2 * k + 1]
            if not value.StatusCode.is_good():
                self.no_channel = f"node {node_id}: {value.StatusCode.name}"
                return None
            if (
                not access.StatusCode.is_good()
                or not int(access.Value.Value) & ua.AccessLevel.CurrentWrite.mask
            ):
                self.no_channel = f"node {node_id} is not writable"
                return None
        return OpcUaTargets(self, self.target_ids, UNIT_TO_DEG[self.unit])

    def close(self) -> None:
        client, self._client = self._client, None
        if client is None:
            return
        try:
            client.disconnect()
        except Exception:  # noqa: BLE001 - a link already gone: nothing left to close but the loop
            client.tloop.stop()

    def read(self) -> Reading:
        if self._client is None:
            raise DeviceUnreachable(self.name, f"OPC UA {self.url} not connected (open() first)")
        values, stamp = self._read_values()
        fields, self._last = self._joints(values, time.monotonic(), stamp, self._last)
        return Reading.now(self.name, fields, OPCUA_FIELDS)

    def received(self) -> list[Reading] | None:
        """With a subscription (module notes), a reading per source timestamp changed since the
        last call, oldest first, stamped at its last change's arrival; None where polled."""
        if self.subscription_ms <= 0:
            return None
        if self._client is None:
            raise DeviceUnreachable(self.name, f"OPC UA {self.url} not connected (open() first)")
        if time.monotonic() - self._checked > self.timeout_s:
            self._read_values()  # the link still answers (module notes)
            self._checked = time.monotonic()
        with self._lock:
            changes = self._pending + list(self._changes)
            self._changes.clear()
        changes.sort(key=lambda c: _seconds(c[1]))
        newest = _seconds(changes[-1][1]) if changes else None
        waited = changes and time.monotonic() - changes[-1][2] > 2e-3 * self.subscription_ms
        self._pending = [] if waited else [c for c in changes if _seconds(c[1]) == newest]
        readings, units = [], {name: field.units for name, field in OPCUA_FIELDS.items()}
        for stamp, group in _by_stamp(changes[: len(changes) - len(self._pending)]):
            for node, value, _, _ in group:
                self._held[node] = self._value(self.node_ids[node], value.Value, speed=node >= JOINTS)
            if len(self._held) < len(self.node_ids) or (self._pushed and stamp <= self._pushed[0]):
                continue  # an axis not heard from yet, or a change older than a reading given
            values = [self._held[k] for k in range(len(self.node_ids))]
            fields, self._pushed = self._joints(values, stamp, stamp, self._pushed)
            readings.append(Reading(self.name, fields, units, group[-1][2], group[-1][3]))
        return readings

    def _joints(self, values: list[float], at: float, stamp: float, last) -> tuple[dict, tuple]:
        """The reading's fields from the nodes' ``values`` (the config's unit), taken at ``at`` [s]
        with source timestamp ``stamp``, and what the next call's speed needs; ``last`` (the
        previous ``(at, q)`` on the same clock, or None) gives the speed where there are no speed
        nodes."""
        factor = UNIT_TO_DEG[self.unit]
        q = tuple(v * factor for v in values[:JOINTS])
        if self._speeds:
            qd = tuple(v * factor for v in values[JOINTS:])
        elif last is None or at <= last[0]:
            qd = (math.inf,) * JOINTS  # unknown until a second read: not settled
        else:
            qd = tuple((a - b) / (at - last[0]) for a, b in zip(q, last[1], strict=True))
        return {"q_deg": q, "qd_deg_s": qd, "robot_mode": RUNNING, "controller_time_s": stamp}, (at, q)

    def _read_values(self) -> tuple[list[float], float]:
        """Every node's value (one Read request) and joint 1's source timestamp [s since epoch]."""
        params = ua.ReadParameters()
        for node in self._nodes:
            rv = ua.ReadValueId()
            rv.NodeId, rv.AttributeId = node.nodeid, ua.AttributeIds.Value
            params.NodesToRead.append(rv)
        try:
            results = self._client.tloop.post(self._client.aio_obj.uaclient.read(params))
        except (asyncio.TimeoutError, TimeoutError) as exc:
            raise DeviceTimeout(self.name, self._silent) from exc
        except (OSError, ConnectionError, ThreadLoopNotRunning, ua.UaError) as exc:
            raise DeviceUnreachable(self.name, f"OPC UA {self.url}: {_why(exc)}") from exc
        out = []
        for k, (node_id, result) in enumerate(zip(self.node_ids, results, strict=True)):
            if not result.StatusCode.is_good():
                raise DeviceReplyError(
                    self.name,
                    f"OPC UA {self.url}: node {node_id}: {result.StatusCode.name}",
                    code=result.StatusCode.name,
                )
            out.append(self._value(node_id, result.Value, speed=k >= JOINTS))
        stamp = results[0].SourceTimestamp or results[0].ServerTimestamp
        return out, stamp.timestamp() if stamp else math.nan

    def _value(self, node_id: str, variant: ua.Variant, speed: bool) -> float:
        """A node's number in the config's unit: a value of another type (a Boolean, a String, an
        array) is a DeviceReplyError (the node is not an axis's), an angle beyond ``MAX_JOINT_DEG``
        or a speed that is no number a GarbledReply (retried, as RTDE's)."""
        value = variant.Value
        if variant.VariantType not in NUMBERS or isinstance(value, list):
            kind = "an array" if isinstance(value, list) else f"a {variant.VariantType.name}"
            raise DeviceReplyError(
                self.name,
                f"OPC UA {self.url}: node {node_id} holds {excerpt(repr(value))}, {kind}, not a number",
                "NOT_A_NUMBER",
            )
        value = float(value)
        unit = f"{self.unit}/s" if speed else self.unit
        if not math.isfinite(value) or (not speed and abs(value * UNIT_TO_DEG[self.unit]) > MAX_JOINT_DEG):
            what = "a speed" if speed else f"an angle within +-{MAX_JOINT_DEG:g} deg"
            raise GarbledReply(
                self.name, f"OPC UA {self.url}: node {node_id} holds {value:g} {unit}, not {what}"
            )
        return value


class _Changes:
    """The subscription's handler: each node's new value to its source."""

    def __init__(self, source: OpcUaJointSource):
        self.index = {node.nodeid: k for k, node in enumerate(source._nodes)}
        self.source = source

    def datachange_notification(self, node, val, data) -> None:
        self.source._changed(self.index[node.nodeid], data.monitored_item.Value)


def _every_sample(node, handle: int) -> ua.MonitoredItemCreateRequest:
    """A request to monitor ``node``'s value with a queue, reporting a sample whose timestamp
    changed even where its value did not (a robot standing still: otherwise no news, as if lost)."""
    item = ua.ReadValueId(NodeId=node.nodeid, AttributeId=ua.AttributeIds.Value)
    trigger = ua.DataChangeFilter(Trigger=ua.DataChangeTrigger.StatusValueTimestamp)
    wanted = ua.MonitoringParameters(
        ClientHandle=handle + 1, QueueSize=QUEUE, DiscardOldest=True, Filter=trigger
    )
    return ua.MonitoredItemCreateRequest(
        ItemToMonitor=item, MonitoringMode=ua.MonitoringMode.Reporting, RequestedParameters=wanted
    )


def _seconds(value: ua.DataValue) -> float:
    """A value's source timestamp (else the server's) [s since the epoch]; NaN without either."""
    stamp = value.SourceTimestamp or value.ServerTimestamp
    return stamp.timestamp() if stamp else math.nan


def _by_stamp(changes: list) -> list[tuple[float, list]]:
    """Changes sorted by timestamp, grouped by it."""
    groups: list[tuple[float, list]] = []
    for change in changes:
        stamp = _seconds(change[1])
        if groups and groups[-1][0] == stamp:
            groups[-1][1].append(change)
        else:
            groups.append((stamp, [change]))
    return groups


def _why(exc: BaseException) -> str:
    """An exception's message, or its kind where it has none (asyncio's timeouts)."""
    return str(exc) or type(exc).__name__


class OpcUaTargets:
    """The target channel of an :class:`OpcUaJointSource`: six position nodes and the index node."""

    def __init__(self, source: OpcUaJointSource, node_ids: list[str], unit_to_deg: float):
        self.source, self.node_ids, self.unit_to_deg = source, node_ids, unit_to_deg
        self.where = f"OPC UA {source.url} nodes {node_ids[0]} .. and {node_ids[-1]}"

    def write(self, target: int, q_deg) -> None:
        """One Write request: the six positions (in the source's unit), then the index."""
        values = [ua.Variant(float(v) / self.unit_to_deg, ua.VariantType.Double) for v in q_deg]
        values.append(ua.Variant(int(target), ua.VariantType.Int32))
        params = ua.WriteParameters()
        for node_id, value in zip(self.node_ids, values, strict=True):
            wv = ua.WriteValue()
            wv.NodeId, wv.AttributeId = ua.NodeId.from_string(node_id), ua.AttributeIds.Value
            wv.Value = ua.DataValue(value)
            params.NodesToWrite.append(wv)
        client = self.source._client
        if client is None:
            raise DeviceUnreachable(self.source.name, f"OPC UA {self.source.url} not connected")
        try:
            codes = client.tloop.post(client.aio_obj.uaclient.write(params))
        except (
            asyncio.TimeoutError,
            TimeoutError,
            OSError,
            ConnectionError,
            ThreadLoopNotRunning,
            ua.UaError,
        ) as exc:
            raise DeviceUnreachable(
                self.source.name,
                f"OPC UA {self.source.url}: writing target {target}: {_why(exc)}",
            ) from exc
        bad = next(((n, c) for n, c in zip(self.node_ids, codes, strict=True) if not c.is_good()), None)
        if bad is not None:
            raise DeviceReplyError(
                self.source.name,
                f"OPC UA {self.source.url}: writing node {bad[0]}: {bad[1].name}",
                bad[1].name,
            )
