"""Robot joint angles: a UR controller over RTDE (``ur_rtde``), or joint registers over Modbus TCP
(a device on :class:`drivers.modbus.ModbusRegisterDriver`).

Both sources read joints in degrees (the controller sends radians over RTDE; Modbus controllers
publish scaled integers or floats, declared once in :data:`JOINT_ENCODINGS`).

RTDE notes (ur_rtde 1.6):

- ``RTDEReceiveInterface(host, frequency, variables)`` connects to port 30004 (fixed), holds the
  GIL and blocks until the first data package arrives. A controller that accepts the TCP
  connection but stalls anywhere in the handshake would hang it (or fill stderr with its
  "boost system Exception" lines), and it unpacks whatever types the controller names for the
  recipe. So :meth:`RtdeJointSource.open` first walks the whole handshake itself, each step
  answered within ``probe_timeout_s``: protocol version, controller version, the output recipe
  (its types checked: ``actual_q`` must be VECTOR6D, ...), start, and one data package of the
  recipe's size with finite values; only then does ur_rtde connect.
- Every reading is checked: finite joints and speeds, a known robot mode; ``package_age_s`` says
  how much later than usual the package arrived (controller timestamp against the local clock,
  the usual link latency being the least seen since open, allowed to drift 1 ms/s).
- After the link drops, ``isConnected()`` turns false (EOF at once; a silent controller after
  ur_rtde's 2.5 s read deadline) and ``read()`` raises :class:`DeviceUnreachable`. The reconnect
  path is :func:`drivers.base.call_with_reconnect` (close, back off, open). It builds a fresh
  interface rather than calling ur_rtde's ``reconnect()``, which resets the frequency from the
  controller version and waits for the first package without checking the link.

Corrected targets (:meth:`RtdeJointSource.target_channel`): written to RTDE input registers by
ur_rtde's ``RTDEIOInterface`` in its upper range (clear of RTDEControlInterface's and of the lower
range other programs use), which offers five double and five integer registers, 42 .. 46: joints
1 .. 5 [rad] in ``input_double_register_42`` .. ``46``, joint 6 [urad] in
``input_int_register_43``, and the target's index plus one in ``input_int_register_42`` (0, the
registers' value at power-on: none; set so when the channel opens), written last (``station
program``'s URScript takes the joints when the index names its next target, and reads the index
again after them). A controller that refuses those inputs (another client writes them)
gives no channel (``no_channel`` says why).

The ``RTDEIOInterface`` lives in a child process (:mod:`drivers.rtde_inputs`): nothing reads its
socket after the handshake, so it still calls itself connected after the controller has gone, its
``disconnect()`` then raises (``read: End of file``, the pause request unanswered) and its
destructor, which calls ``disconnect()`` again, throws out of a C++ destructor: ``std::terminate``
("write: Broken pipe"), SIGABRT for the process that drops it, mid-session at a controller reboot.
The child never runs that destructor; the station asks it to disconnect, waits ``CLOSE_S`` and ends
it either way, so a controller gone, frozen or unplugged costs at most a second, and the channel
comes back with the next open (:func:`drivers.base.call_with_reconnect`) and the next write.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import select
import socket
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import rtde_receive
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from drivers.base import (
    DeviceReplyError,
    DeviceTimeout,
    DeviceUnreachable,
    Driver,
    DriverError,
    Field,
    GarbledReply,
    IncompatibleDevice,
    Reading,
    excerpt,
)
from drivers.modbus import ModbusRegisterDriver
from drivers.registers import DataType, Encoding, RegisterLayout

RTDE_PORT = 30004
TARGET_INDEX_INPUT = 42  # input_int_register_42: the corrected target's index + 1, 0: none (module notes)
TARGET_JOINT_INPUTS = (42, 43, 44, 45, 46)  # input_double_register_*: joints 1 .. 5 [rad]
TARGET_JOINT6_INPUT = 43  # input_int_register_43: joint 6 [urad]
URAD = 1e6  # joint 6's register counts per radian
RTDE_VARIABLES = ("timestamp", "actual_q", "actual_qd", "robot_mode")
JOINTS = 6
INPUTS_WRITER = Path(__file__).with_name("rtde_inputs.py")  # the child that writes them (RtdeTargets)

RTDE_TYPES = ("DOUBLE", "VECTOR6D", "VECTOR6D", "INT32")  # of RTDE_VARIABLES (UR's RTDE guide)
_DATA = struct.Struct(">B d 6d 6d i")  # a data package of that recipe: recipe id, then the values
ROBOT_MODES = range(-1, 9)  # UR robot_mode: -1 NO_CONTROLLER .. 8 UPDATING_FIRMWARE
CLOCK_DRIFT = 1e-3  # s/s the controller's clock may run slower than ours

RTDE_FIELDS = {
    "q_deg": Field("deg", (JOINTS,), "actual joint positions"),
    "qd_deg_s": Field("deg/s", (JOINTS,), "actual joint velocities"),
    "robot_mode": Field("", (), "UR robot mode (7 = RUNNING)"),
    "controller_time_s": Field("s", (), "controller timestamp of the data package"),
    "package_age_s": Field("s", (), "how much later than usual the package arrived"),
}

# RTDE protocol-version request and its reply (UR RTDE guide): header uint16 size + uint8 'V'.
_PROBE_REQUEST = struct.pack(">HBH", 5, ord("V"), 2)
_PROBE_REPLY = struct.pack(">HBB", 4, ord("V"), 1)
_HEADER = struct.Struct(">HB")


class RtdeJointSource(Driver):
    """Joints of a UR controller at ``host`` over RTDE, read at ``frequency_hz`` (<= 500).

    ``read()`` gives the latest data package; a package older than ``stale_s`` (the controller
    stopped streaming) raises :class:`DeviceTimeout`.
    """

    fields = RTDE_FIELDS

    def __init__(
        self,
        host: str,
        frequency_hz: float = 500.0,
        *,
        name: str = "robot",
        stale_s: float = 0.5,
        probe_timeout_s: float = 1.0,
    ):
        if not 0 < frequency_hz <= 500:
            raise ValueError(f"frequency_hz must be in (0, 500], got {frequency_hz}")
        self.name = name
        self.host = host
        self.frequency_hz = float(frequency_hz)
        self.stale_s = stale_s
        self.probe_timeout_s = probe_timeout_s
        self._rtde = None
        self._last_stamp = math.nan
        self._last_change = 0.0
        self._silent = False  # the last read found no new package for stale_s
        self._latency = (math.inf, 0.0)  # least (local - controller time) seen, and when [s]
        self._targets: RtdeTargets | None = None
        self.no_channel: str | None = None

    @property
    def _where(self) -> str:
        return f"RTDE {self.host}:{RTDE_PORT}"

    def open(self) -> None:
        """Probe the controller, then start ur_rtde's receive interface."""
        self._probe()
        try:
            self._rtde = rtde_receive.RTDEReceiveInterface(self.host, self.frequency_hz, list(RTDE_VARIABLES))
        except RuntimeError as exc:
            if "not found by the controller" in str(exc):
                raise DeviceReplyError(
                    self.name, f"{self._where} lacks a variable: {exc}", code="NOT_FOUND"
                ) from exc
            raise DeviceUnreachable(self.name, f"{self._where}: {exc}") from exc
        self._last_stamp, self._last_change = math.nan, time.monotonic()
        self._latency = (math.inf, 0.0)

    def _probe(self) -> None:
        """Walk the RTDE handshake up to the first data package, every step within
        ``probe_timeout_s``, and check what the controller answers."""
        step = "the connection"
        try:
            with socket.create_connection((self.host, RTDE_PORT), self.probe_timeout_s) as s:
                s.settimeout(self.probe_timeout_s)
                step = "the protocol request"
                s.sendall(_PROBE_REQUEST)
                reply = _recv_exactly(s, len(_PROBE_REPLY))
                if reply != _PROBE_REPLY:
                    raise GarbledReply(
                        self.name,
                        f"{self._where} answered the protocol request with "
                        f"{excerpt(reply.hex(' '), len(reply))}, expected {_PROBE_REPLY.hex(' ')}",
                    )
                step = "the controller version request"
                self._ask(s, "v")
                step = "the output recipe request"
                self._check_recipe(self._ask(s, "O", struct.pack(">d", self.frequency_hz) + _names()))
                step = "the start request"
                if self._ask(s, "S") != b"\x01":
                    raise IncompatibleDevice(self.name, f"{self._where} refused to start streaming")
                step = "a data package after start"
                self._check_package(self._receive(s, "U"))
        except TimeoutError as exc:
            raise DeviceTimeout(
                self.name, f"{self._where} did not answer {step} within {self.probe_timeout_s} s"
            ) from exc
        except OSError as exc:
            where = (
                f"cannot connect to {self._where}" if step == "the connection" else f"{self._where}: {step}"
            )
            raise DeviceUnreachable(self.name, f"{where}: {exc}") from exc

    def _ask(self, s: socket.socket, kind: str, payload: bytes = b"") -> bytes:
        """Send one request of type ``kind``; its reply's payload."""
        s.sendall(_HEADER.pack(_HEADER.size + len(payload), ord(kind)) + payload)
        return self._receive(s, kind)

    def _receive(self, s: socket.socket, kind: str) -> bytes:
        """The payload of the next package of type ``kind`` (text messages skipped)."""
        while True:
            header = _recv_exactly(s, _HEADER.size)
            if len(header) < _HEADER.size:
                raise DeviceUnreachable(self.name, f"{self._where} closed the connection")
            size, got = _HEADER.unpack(header)
            payload = _recv_exactly(s, max(0, size - _HEADER.size))
            if got == ord(kind):
                return payload
            if got != ord("M"):
                package = header + payload
                raise GarbledReply(
                    self.name,
                    f"{self._where} answered {kind!r} with a {chr(got)!r} package "
                    f"{excerpt(package.hex(' '), len(package))}",
                )

    def _check_recipe(self, reply: bytes) -> None:
        """The controller's types for the recipe must be UR's (else ur_rtde unpacks garbage)."""
        types = reply[1:].decode("ascii", errors="replace").split(",")
        for name, want, got in zip(RTDE_VARIABLES, RTDE_TYPES, types + [""] * len(RTDE_TYPES), strict=False):
            if got == "NOT_FOUND":
                raise DeviceReplyError(
                    self.name,
                    f"{self._where} lacks a variable: {name} not found by the controller",
                    code="NOT_FOUND",
                )
            if got != want:
                raise IncompatibleDevice(
                    self.name,
                    f"{self._where} types {name} as {excerpt(got)}, not {want}: "
                    "not a UR controller's recipe, refused",
                )

    def _check_package(self, payload: bytes) -> None:
        """The first data package: the recipe's size and finite values."""
        if len(payload) != _DATA.size:
            raise GarbledReply(
                self.name,
                f"{self._where} sent a data package of {len(payload) + _HEADER.size} bytes, "
                f"the recipe makes {_DATA.size + _HEADER.size}",
            )
        values = _DATA.unpack(payload)[1:]
        if not all(math.isfinite(v) for v in values):
            raise GarbledReply(
                self.name, f"{self._where} sent a data package with values that are not numbers"
            )

    def target_channel(self) -> RtdeTargets | None:
        """The input registers (module notes), through a second RTDE connection opened at the
        first ask; None if the controller refuses them (``no_channel``: why)."""
        if self._targets is None and self.no_channel is None:
            try:
                self._targets = RtdeTargets(self.name, self.host)
            except RuntimeError as exc:
                self.no_channel = f"{self._where} refused its input registers: {exc}"
            except DriverError as exc:  # the writer did not answer: no channel until the next open
                self.no_channel = exc.cause
        return self._targets

    def close(self) -> None:
        """Drop the interface; its destructor pauses the stream (if the link is up) and
        disconnects. After a silent controller, first let ur_rtde's read deadline (2.5 s) mark
        the link down: its pause request would otherwise wait for a reply that never comes. The
        target channel, if open, is ended (:meth:`RtdeTargets.close`: never raises, at most
        ``CLOSE_S``) and opened again at the next ask after the next open."""
        rtde, self._rtde = self._rtde, None
        targets, self._targets, self.no_channel = self._targets, None, None
        if targets is not None:
            targets.close()
        if rtde is not None and self._silent:
            deadline = time.monotonic() + 3.0
            while rtde.isConnected() and time.monotonic() < deadline:
                time.sleep(0.01)
        self._silent = False

    def read(self) -> Reading:
        if self._rtde is None:  # never opened, or the last reopen failed: retryable
            raise DeviceUnreachable(self.name, f"{self._where} not connected (open() first)")
        if not self._rtde.isConnected():
            raise DeviceUnreachable(self.name, f"{self._where} connection lost")
        stamp, q, qd, mode = self._consistent_sample()
        now = time.monotonic()
        if not all(math.isfinite(v) for v in (stamp, *q, *qd)) or len(q) != JOINTS or mode not in ROBOT_MODES:
            raise GarbledReply(
                self.name,
                f"{self._where} sent a package that is no robot state "
                f"(joints {excerpt(repr(list(q)))}, robot mode {mode})",
            )
        if stamp != self._last_stamp:
            self._last_stamp, self._last_change = stamp, now
        elif now - self._last_change > self.stale_s:
            self._silent = True
            raise DeviceTimeout(
                self.name, f"no new data package from {self._where} for {now - self._last_change:.2f} s"
            )
        values = {
            "q_deg": tuple(math.degrees(v) for v in q),
            "qd_deg_s": tuple(math.degrees(v) for v in qd),
            "robot_mode": int(mode),
            "controller_time_s": stamp,
            "package_age_s": self._age(now, stamp),
        }
        return Reading.now(self.name, values, RTDE_FIELDS)

    def _age(self, now: float, stamp: float) -> float:
        """How much later than the least latency seen the package ``stamp`` is read at ``now``."""
        least, since = self._latency
        least = min(least + CLOCK_DRIFT * (now - since), now - stamp)
        self._latency = (least, now)
        return (now - stamp) - least

    def _consistent_sample(self) -> tuple[float, list, list, int]:
        """Timestamp, q, qd and mode of one package: ur_rtde's getters lock per call, so read
        again if a newer package landed in between (at most three tries)."""
        rtde = self._rtde
        for _ in range(3):
            stamp = rtde.getTimestamp()
            sample = (stamp, rtde.getActualQ(), rtde.getActualQd(), rtde.getRobotMode())
            if rtde.getTimestamp() == stamp:
                break
        return sample


class RtdeTargets:
    """A UR controller's input registers for corrected targets (module notes), written by ur_rtde's
    ``RTDEIOInterface`` (upper range) in a child process (:mod:`drivers.rtde_inputs` says why: an IO
    interface whose controller has gone aborts the process that drops it). Every exchange with the
    child is bounded in time; one that it does not answer ends it (the kernel closes its socket).

    Raises ``RuntimeError`` (ur_rtde's words) where the controller refuses the registers, and
    :class:`DeviceTimeout` or :class:`DeviceUnreachable` where the writer does not answer."""

    OPEN_S = 5.0  # connection, protocol, five input recipes and ur_rtde's 0.1 s wait
    WRITE_S = 2.0  # the seven registers (socket writes: nothing to wait for but the scheduler)
    CLOSE_S = 1.0  # the pause request answered (a controller gone or frozen never answers)

    def __init__(self, name: str, host: str):
        self.name, self.host = name, host
        self.where = (
            f"RTDE {host}:{RTDE_PORT} input registers (int {TARGET_INDEX_INPUT}: index + 1, double "
            f"{TARGET_JOINT_INPUTS[0]}..{TARGET_JOINT_INPUTS[-1]}: joints 1-5 rad, "
            f"int {TARGET_JOINT6_INPUT}: joint 6 urad)"
        )
        self._buffer = b""
        self._lock = threading.Lock()
        self._child = subprocess.Popen(  # no target yet (not a previous session's): it clears the index
            [sys.executable, str(INPUTS_WRITER), host, str(TARGET_INDEX_INPUT)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        try:
            answer = self._exchange(None, self.OPEN_S, "opening its input registers")
        except DriverError:
            self.close()
            raise
        if "error" in answer:
            self.close()
            raise RuntimeError(answer["error"])

    def close(self) -> None:
        """Disconnect (where the controller answers within ``CLOSE_S``) and end the writer; never
        raises, safe to call twice."""
        with self._lock:
            child, self._child = self._child, None
        if child is None:
            return
        try:
            if child.poll() is None:
                child.stdin.write(b'{"op": "close"}\n')
                child.stdin.flush()
                child.wait(self.CLOSE_S)
        except (OSError, subprocess.TimeoutExpired):
            pass
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
            for pipe in (child.stdin, child.stdout):
                with contextlib.suppress(OSError):
                    pipe.close()

    def write(self, target: int, q_deg) -> None:
        """The joints, then the index (the program reads the index before and after the joints)."""
        q = [math.radians(v) for v in q_deg]
        registers = [["double", r, v] for r, v in zip(TARGET_JOINT_INPUTS, q[:5], strict=True)]
        registers.append(["int", TARGET_JOINT6_INPUT, round(q[5] * URAD)])
        registers.append(["int", TARGET_INDEX_INPUT, int(target) + 1])  # last
        doing = f"writing target {target}"
        answer = self._exchange({"op": "write", "registers": registers}, self.WRITE_S, doing)
        if "error" in answer:
            raise DeviceUnreachable(self.name, f"RTDE {self.host}:{RTDE_PORT}: {doing}: {answer['error']}")
        if not answer.get("ok"):
            raise DeviceUnreachable(self.name, f"RTDE {self.host}:{RTDE_PORT}: {doing} failed")

    def _exchange(self, request: dict | None, timeout_s: float, doing: str) -> dict:
        """Send ``request`` (None: nothing, the first reply) and read the child's reply within
        ``timeout_s``; a child that ended or does not answer is ended, and said."""
        with self._lock:
            child = self._child
            where = f"RTDE {self.host}:{RTDE_PORT}: {doing}"
            if child is None:
                raise DeviceUnreachable(self.name, f"{where}: the target channel is closed")
            try:
                if request is not None:
                    child.stdin.write(json.dumps(request).encode() + b"\n")
                    child.stdin.flush()
                line = self._line(child, time.monotonic() + timeout_s)
            except OSError:
                line = b""
            if line:
                return json.loads(line)
            if child.poll() is None:
                child.kill()
                child.wait()
                raise DeviceTimeout(self.name, f"{where}: ur_rtde did not answer within {timeout_s:g} s")
            raise DeviceUnreachable(
                self.name, f"{where}: ur_rtde's writer ended (exit code {child.returncode})"
            )

    def _line(self, child: subprocess.Popen, deadline: float) -> bytes:
        """The child's next reply line, or b"" if it ends first or ``deadline`` passes."""
        fd = child.stdout.fileno()
        while b"\n" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return b""
            chunk = os.read(fd, 4096)
            if not chunk:
                return b""
            self._buffer += chunk
        line, self._buffer = self._buffer.split(b"\n", 1)
        return line


def target_from_inputs(inputs) -> tuple[float, ...]:
    """The corrected target's joints [deg] in a controller's input registers ``inputs`` (by RTDE
    name: what :class:`RtdeTargets` writes)."""
    q = [float(inputs.get(f"input_double_register_{r}", math.nan)) for r in TARGET_JOINT_INPUTS]
    q.append(float(inputs.get(f"input_int_register_{TARGET_JOINT6_INPUT}", 0)) / URAD)
    return tuple(math.degrees(v) for v in q)


def _names() -> bytes:
    return ",".join(RTDE_VARIABLES).encode("ascii")


def _recv_exactly(sock: socket.socket, n: int) -> bytes:
    """``n`` bytes from ``sock`` (fewer only if the peer closes)."""
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            break
        data += chunk
    return data


JOINT_ENCODINGS: dict[str, Encoding] = {
    "int32_mdeg": Encoding(DataType.INT32, 0.001),  # signed millidegrees, 2 registers
    "float32_deg": Encoding(DataType.FLOAT32, 1.0),  # IEEE-754 single degrees, 2 registers
}


@dataclass(frozen=True)
class JointRegisterMap(RegisterLayout):
    """Where a controller publishes its six joints: consecutive values from ``address`` (joint 1
    first); ``q_deg = raw * unit_per_count * scale``. Defaults: holding register 0, device id 1,
    INT32 millidegrees, high word first."""

    ENCODINGS: ClassVar[dict[str, Encoding]] = JOINT_ENCODINGS
    VALUES: ClassVar[int] = JOINTS

    encoding: str = "int32_mdeg"

    def decode_deg(self, registers: list[int]) -> tuple[float, ...]:
        """Six joint angles (deg) from the raw registers."""
        return self.decode(registers)

    def encode_deg(self, q_deg) -> list[int]:
        """The registers a controller publishes for ``q_deg`` (inverse of :meth:`decode_deg`)."""
        return self.encode(q_deg)


MODBUS_FIELDS = {"q_deg": Field("deg", (JOINTS,), "joint positions from the controller")}


class ModbusJointSource(ModbusRegisterDriver):
    """Joints read from a controller's Modbus registers (see
    :class:`drivers.modbus.ModbusRegisterDriver` for ``client``): ``q_deg``, joint 1 first."""

    fields = MODBUS_FIELDS
    field = "q_deg"
    what = "joint registers"

    def __init__(
        self,
        client: ModbusTcpClient | ModbusSerialClient,
        registers: JointRegisterMap = JointRegisterMap(),
        name: str = "robot",
    ):
        super().__init__(client, registers, name)
