"""A controller's OPC UA server (``asyncua``) publishing the simulated robot's joints.

Laid out as the OPC UA Robotics companion specification (OPC 40010-1) lays out a motion device:
``Objects/DeviceSet/Robot/Axes/Axis<i>/ParameterSet/ActualPosition`` (deg) and ``ActualSpeed``
(deg per simulated s), each with a string node id of that path in the server's namespace 2
(:func:`position_node`, :func:`speed_node`). Every read computes the value from the robot program at
that instant (a value callback), stamped with the time it was read. With ``sample_s``, while a
client holds a subscription, the server also samples the program every ``sample_s`` [s] as a
controller's cycle does and writes every axis's position and speed with that sample's one
timestamp, so monitored items see each sample (reads stay computed on read). The server runs its
own event loop in a thread; ``start()`` returns once it listens, ``stop()`` ends it.

The target channel (no part of the companion specification: what a controller program or gateway
offers a station that corrects targets in-session): writable ``TargetPosition`` (Double, deg)
beside each axis's ``ActualPosition``, and ``DeviceSet/Robot/TargetIndex`` (Int32). Writing the
index commits the positions written before it: ``hand(target, q_deg)``, the program's channel.

A hostile or unusual server (tests): ``edit(joint, index, value)`` (joint 0 .. 5, index 0 for the
position and 1 for the speed) gets the ``ua.DataValue`` a read would answer and returns the one to
answer instead: another type, no number, an old timestamp, or a wait that stalls the server.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
from collections import deque
from datetime import datetime, timezone

from asyncua import Server, ua

logging.getLogger("asyncua").setLevel(logging.CRITICAL)  # its notes and tracebacks: start() reports

NAMESPACE = "urn:station:sim:robot"
AXES = 6


def position_node(axis: int) -> str:
    """Node id of axis ``axis``'s (1..6) ActualPosition."""
    return f"ns=2;s=DeviceSet/Robot/Axes/Axis{axis}/ParameterSet/ActualPosition"


def speed_node(axis: int) -> str:
    """Node id of axis ``axis``'s (1..6) ActualSpeed."""
    return f"ns=2;s=DeviceSet/Robot/Axes/Axis{axis}/ParameterSet/ActualSpeed"


def target_node(axis: int) -> str:
    """Node id of axis ``axis``'s (1..6) TargetPosition (writable, deg): a corrected target's joint."""
    return f"ns=2;s=DeviceSet/Robot/Axes/Axis{axis}/ParameterSet/TargetPosition"


TARGET_INDEX_NODE = "ns=2;s=DeviceSet/Robot/TargetIndex"
"""Node id of the corrected target's index (writable, Int32): writing it commits the positions."""


class OpcUaRobotServer:
    """Serves ``state()`` (a callable returning joints [deg] and speeds [deg/s], (6,) each) at
    ``opc.tcp://host:port``; ``hand(target, q_deg)`` hears each corrected target written;
    ``sample_s``: the cycle [s] at which subscribed clients get samples (module notes; None: none)."""

    def __init__(self, state, host: str, port: int = 4840, hand=None, sample_s: float | None = None):
        self.state, self.host, self.port, self.hand, self.sample_s = state, host, port, hand, sample_s
        self._target = [math.nan] * AXES
        self.url = f"opc.tcp://{host}:{port}"
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="opcua-sim", daemon=True)
        self.edit = None  # (joint, index, ua.DataValue) -> ua.DataValue: see the module notes
        self.sampled: deque[float] = deque(maxlen=100_000)  # each sample's timestamp [s since epoch]

    def start(self) -> OpcUaRobotServer:
        self._thread.start()
        self._ready.wait(30.0)
        if self._error is not None:
            raise RuntimeError(f"OPC UA server at {self.url}: {self._error}") from self._error
        if not self._ready.is_set():
            raise RuntimeError(f"OPC UA server at {self.url} did not start within 30 s")
        return self

    def stop(self) -> None:
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(10.0)

    def _run(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported to start() in the caller's thread
            self._error = exc
            self._ready.set()

    async def _serve(self) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        server = Server()
        await server.init()
        server.set_endpoint(self.url)
        server.set_server_name("station simulated robot controller")
        ns = await server.register_namespace(NAMESPACE)
        folder, actual = server.nodes.objects, []
        for name in ("DeviceSet", "Robot", "Axes"):
            folder = await folder.add_object(ua.NodeId(f"{_path(folder)}{name}", ns), name)
        for axis in range(1, AXES + 1):
            obj = await folder.add_object(ua.NodeId(f"DeviceSet/Robot/Axes/Axis{axis}", ns), f"Axis{axis}")
            params = await obj.add_object(
                ua.NodeId(f"DeviceSet/Robot/Axes/Axis{axis}/ParameterSet", ns), "ParameterSet"
            )
            for key, index in (("ActualPosition", 0), ("ActualSpeed", 1)):
                node_id = ua.NodeId(f"DeviceSet/Robot/Axes/Axis{axis}/ParameterSet/{key}", ns)
                await params.add_variable(node_id, key, 0.0, varianttype=ua.VariantType.Double)
                server.set_attribute_value_callback(node_id, self._reader(axis - 1, index))
                # a sample written for the monitored items leaves the read callback in place
                server.set_attribute_value_setter(node_id, lambda node, attr, value: None)
                actual.append((axis - 1, index, node_id))
            key = "TargetPosition"
            node_id = ua.NodeId(f"DeviceSet/Robot/Axes/Axis{axis}/ParameterSet/{key}", ns)
            node = await params.add_variable(node_id, key, math.nan, varianttype=ua.VariantType.Double)
            await node.set_writable()
            server.set_attribute_value_setter(node_id, self._setter(axis - 1))
        robot = server.get_node(ua.NodeId("DeviceSet/Robot", ns))
        index_id = ua.NodeId("DeviceSet/Robot/TargetIndex", ns)
        node = await robot.add_variable(index_id, "TargetIndex", -1, varianttype=ua.VariantType.Int32)
        await node.set_writable()
        server.set_attribute_value_setter(index_id, self._setter(None))
        async with server:
            self._ready.set()
            if self.sample_s is None:
                await self._stop.wait()
            else:
                await self._sample(server, actual)

    async def _sample(self, server: Server, actual: list) -> None:
        """Until stopped: while a client subscribes, every ``sample_s`` one sample of the program
        written to every axis node with one timestamp (module notes)."""
        subscriptions = server.iserver.subscription_service.subscriptions
        while not self._stop.is_set():
            if subscriptions:
                state, now = self.state(), datetime.now(timezone.utc)
                self.sampled.append(now.timestamp())
                for joint, index, node_id in actual:
                    answer = ua.DataValue(
                        ua.Variant(float(state[index][joint]), ua.VariantType.Double),
                        SourceTimestamp=now,
                        ServerTimestamp=now,
                    )
                    answer = answer if self.edit is None else self.edit(joint, index, answer)
                    await server.write_attribute_value(node_id, answer)
            try:
                await asyncio.wait_for(self._stop.wait(), self.sample_s)
            except asyncio.TimeoutError:
                pass

    def _reader(self, joint: int, index: int):
        """The value callback of one joint's position (index 0) or speed (1)."""

        def read(node_id, attr) -> ua.DataValue:
            value = float(self.state()[index][joint])
            now = datetime.now(timezone.utc)
            answer = ua.DataValue(
                ua.Variant(value, ua.VariantType.Double), SourceTimestamp=now, ServerTimestamp=now
            )
            return answer if self.edit is None else self.edit(joint, index, answer)

        return read

    def _setter(self, joint: int | None):
        """The value setter of one joint's TargetPosition, or (None) of TargetIndex, which commits."""

        def write(node, attr, value: ua.DataValue) -> None:
            node.attributes[attr].value = value
            if joint is not None:
                self._target[joint] = float(value.Value.Value)
            elif self.hand is not None and int(value.Value.Value) >= 0:
                self.hand(int(value.Value.Value), list(self._target))

        return write


def _path(folder) -> str:
    """The string id prefix of the objects below ``folder`` (the root: none)."""
    ident = folder.nodeid.Identifier
    return f"{ident}/" if isinstance(ident, str) else ""
