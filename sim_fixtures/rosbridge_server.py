"""A small rosbridge-protocol server publishing the simulated robot's ``sensor_msgs/JointState``.

The rosbridge v2 protocol over a WebSocket (RFC 6455 text frames, written here on asyncio streams in
a thread of its own: autobahn would bind the process to one async framework, and roslibpy's
client binds it to twisted): a client's
``{"op": "subscribe", "topic": ...}`` for ``topic`` starts ``{"op": "publish", "topic": ...,
"msg": JointState}`` messages at ``rate_hz`` on that connection until it unsubscribes or closes.
The message: ``header.stamp`` (secs, nsecs of the wall clock), ``name`` (``JOINT_NAMES``: the
ROS-Industrial ``joint_1`` .. ``joint_6``), ``position`` [rad], ``velocity`` [rad per simulated s].
A client's ``{"op": "publish", "topic": target_topic, "msg": JointState}`` (the station's corrected
targets: ``header.frame_id`` the target id, ``position`` [rad] in ``JOINT_NAMES``' order) goes to
``hand(target, q_deg)``, the program's channel. Other operations are ignored (``advertise``: a
bridge answers it; the station sends no others). A hostile or unusual publisher (tests):
``edit(message)`` returns what is published instead of each message (any JSON value).
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import math
import struct
import threading
import time

JOINT_NAMES = tuple(f"joint_{i}" for i in range(1, 7))


class RosbridgeServer:
    """Serves ``state()`` (joints [deg] and speeds [deg/s], (6,) each) as JointState on ``topic``
    at ``ws://host:port``; targets published on ``target_topic`` go to ``hand`` (None: dropped)."""

    def __init__(
        self,
        state,
        host: str,
        port: int = 9090,
        topic: str = "/joint_states",
        rate_hz: float = 100.0,
        target_topic: str = "/station/target",
        hand=None,
    ):
        self.state, self.host, self.port, self.topic, self.rate_hz = state, host, port, topic, rate_hz
        self.target_topic, self.hand = target_topic, hand
        self.edit = None  # message -> what is published instead (module notes)
        self.url = f"ws://{host}:{port}"
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="rosbridge-sim", daemon=True)

    def start(self) -> RosbridgeServer:
        self._thread.start()
        self._ready.wait(30.0)
        if self._error is not None:
            raise RuntimeError(f"rosbridge server at {self.url}: {self._error}") from self._error
        return self

    def stop(self) -> None:
        if self._loop is not None and self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop).result(10.0)
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(10.0)

    async def _shutdown(self) -> None:
        """Stop listening and end every connection's tasks."""
        self._server.close()
        tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    def message(self) -> dict:
        """The JointState message of this instant."""
        q_deg, qd_deg_s = self.state()
        now = time.time()
        return {
            "header": {"stamp": {"secs": int(now), "nsecs": int((now % 1) * 1e9)}, "frame_id": ""},
            "name": list(JOINT_NAMES),
            "position": [math.radians(v) for v in q_deg],
            "velocity": [math.radians(v) for v in qd_deg_s],
            "effort": [],
        }

    def _run(self) -> None:
        self._loop = asyncio.new_event_loop()
        try:
            self._server = self._loop.run_until_complete(
                asyncio.start_server(self._serve, self.host, self.port)
            )
        except BaseException as exc:  # noqa: BLE001 - reported to start() in the caller's thread
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            self._loop.run_forever()
        finally:
            self._server.close()
            self._loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        """One bridge connection: the WebSocket handshake, then subscribe/unsubscribe requests."""
        publishing = None
        try:
            request = await reader.readuntil(b"\r\n\r\n")
            key = next(
                line.split(b":", 1)[1].strip()
                for line in request.split(b"\r\n")
                if line.lower().startswith(b"sec-websocket-key:")
            )
            accept = base64.b64encode(hashlib.sha1(key + WS_GUID).digest())
            writer.write(
                b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                b"Sec-WebSocket-Accept: " + accept + b"\r\n\r\n"
            )
            while True:
                opcode, payload = await _read_frame(reader)
                if opcode == 0x8:  # close
                    break
                if opcode != 0x1:
                    continue
                op = json.loads(payload.decode("utf8"))
                if op.get("op") == "publish" and op.get("topic") == self.target_topic:
                    self._take_target(op.get("msg", {}))
                if op.get("topic") != self.topic:
                    continue
                if op.get("op") == "subscribe" and publishing is None:
                    publishing = asyncio.ensure_future(self._publish(writer))
                elif op.get("op") == "unsubscribe" and publishing is not None:
                    publishing.cancel()
                    publishing = None
        except (asyncio.IncompleteReadError, asyncio.CancelledError, ConnectionError, StopIteration):
            pass
        finally:
            if publishing is not None:
                publishing.cancel()
            writer.close()

    def _take_target(self, msg: dict) -> None:
        """A corrected target published by the station, to the program's channel."""
        if self.hand is None:
            return
        names, positions = msg.get("name", []), msg.get("position", [])
        q_deg = [math.degrees(positions[names.index(n)]) for n in JOINT_NAMES]
        self.hand(int(msg["header"]["frame_id"]), q_deg)

    async def _publish(self, writer: asyncio.StreamWriter) -> None:
        while True:
            message = self.message() if self.edit is None else self.edit(self.message())
            text = json.dumps({"op": "publish", "topic": self.topic, "msg": message})
            writer.write(_frame(text.encode("utf8")))
            await writer.drain()
            await asyncio.sleep(1.0 / self.rate_hz)


WS_GUID = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"  # RFC 6455


async def _read_frame(reader: asyncio.StreamReader) -> tuple[int, bytes]:
    """One client frame (RFC 6455: masked): its opcode and unmasked payload."""
    head = await reader.readexactly(2)
    opcode, length = head[0] & 0x0F, head[1] & 0x7F
    if length == 126:
        length = struct.unpack(">H", await reader.readexactly(2))[0]
    elif length == 127:
        length = struct.unpack(">Q", await reader.readexactly(8))[0]
    mask = await reader.readexactly(4) if head[1] & 0x80 else b"\0\0\0\0"
    data = await reader.readexactly(length)
    return opcode, bytes(b ^ mask[i % 4] for i, b in enumerate(data))


def _frame(payload: bytes) -> bytes:
    """A final, unmasked text frame of ``payload``."""
    n = len(payload)
    if n < 126:
        head = struct.pack(">BB", 0x81, n)
    elif n < 1 << 16:
        head = struct.pack(">BBH", 0x81, 126, n)
    else:
        head = struct.pack(">BBQ", 0x81, 127, n)
    return head + payload
