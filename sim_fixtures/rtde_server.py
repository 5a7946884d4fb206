"""A simulated UR controller's RTDE interface, for the real ``ur_rtde`` client.

The server speaks protocol version 2 (:mod:`sim_fixtures.rtde_wire`): it answers ``V`` (accepts
version 2 only), ``v`` (an e-Series version, so ur_rtde picks 500 Hz by default), ``O`` (the real
output types, ``NOT_FOUND`` for names it does not offer), ``I`` (input recipes: the real input
types, ``NOT_FOUND`` for names it does not take, ``IN_USE`` for an input another connection
writes; a recipe with either is refused, id 0), ``S`` and ``P``; after ``S`` it streams ``U``
packages at the recipe's frequency until ``P`` or until the client goes away (EOF or reset is a
normal end). A client's ``U`` package of an accepted input recipe, of exactly the recipe's size,
sets those inputs (any other is dropped and counted, :attr:`RtdeServer.input_errors`); writing
the target index register (``drivers.robot``'s layout, as ``station program``'s URScript reads
it) hands the registered target to the robot program (``inbox(target, q_deg)``). It never sends
a text message (``M``): ur_rtde reads exactly one reply per request during the handshake.

The streamed values come from a robot source, anything picklable whose ``state(t_s)`` gives
``q_deg``, ``qd_deg_s`` and ``robot_mode`` ``t_s`` real seconds after the program started (a
:class:`~sim_fixtures.robot_program.SimRobot`, or the station simulation's source): ``actual_q`` and
``target_q`` in radians, ``actual_qd`` / ``target_qd`` in rad/s, ``robot_mode``, and
``timestamp``, the controller clock: real seconds since the robot program started, so that
``robot.state(timestamp)`` is exactly what the package carries (a restarted server keeps the
program's clock, as if only the network had gone). Fields the simulation does not model are
zeros. Like the real controller, a server that falls behind skips the packages it missed and
sends the most recent state (their timestamps show the gap); :attr:`RtdeServerProcess.skipped`
counts them, to tell server lateness from client misses.

ur_rtde's ``RTDEReceiveInterface`` constructor holds the GIL while it waits for the first data
package, and its port is fixed at 30004: the server must run in another process
(:class:`RtdeServerProcess`), on its own loopback address (127.0.0.x) when tests run in parallel.
RTDEReceiveInterface connects to port 30004 only (no dashboard or script port).

Faults (:class:`RtdeFaults`, fixed for the server's life) make the controller as unkind as a broken
one: a handshake that stalls at one request, an output recipe typing a field otherwise (``actual_q``
as VECTOR3D), a 64 KiB garbage package instead of data, and every n-th package carrying NaN joints
or a state ``late_s`` old (a stream that fell behind).
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import random
import select
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Protocol

from drivers.robot import TARGET_INDEX_INPUT, target_from_inputs
from sim_fixtures import rtde_wire as wire

RTDE_PORT = 30004
MAX_FREQUENCY_HZ = 500.0  # e-Series control loop
GARBAGE_PACKAGE = bytes(random.Random(7).getrandbits(8) for _ in range(0xFFFF - 4))  # 64 KiB of noise
SAFETY_NORMAL = 1  # UR safety_mode NORMAL
RUNTIME_PLAYING = 2  # UR runtime_state PLAYING


class RobotSource(Protocol):
    """The simulated robot: ``state(t_s)`` has ``q_deg``, ``qd_deg_s`` (6 each), ``robot_mode``."""

    def state(self, t_s: float) -> Any: ...


@dataclass(frozen=True)
class ControllerVersion:
    """What ``v`` reports. Major 5 is e-Series: ur_rtde then defaults (and reconnects) at 500 Hz."""

    major: int = 5
    minor: int = 12
    bugfix: int = 0
    build: int = 0


@dataclass(frozen=True)
class RtdeFaults:
    """A broken controller (see the module notes): ``stall_at`` the request letter never answered
    (``V``, ``v``, ``O``, ``S``; ``U``: started, but no data package ever), ``types`` output types
    said instead of the real ones, ``garbage`` the first package replaced by 64 KiB of noise,
    ``nan_every`` / ``late_every`` every n-th package with NaN joints / a state ``late_s`` old."""

    stall_at: str | None = None
    types: tuple[tuple[str, str], ...] = ()
    garbage: bool = False
    nan_every: int = 0
    late_every: int = 0
    late_s: float = 0.2

    def recipe_types(self, names) -> list[str]:
        said = dict(self.types)
        return [said.get(n, t) for n, t in zip(names, wire.output_types(names), strict=True)]

    def spoil(self, outputs: dict, count: int, state_at) -> dict:
        """The ``count``-th package's outputs as this controller sends them."""
        if self.late_every and count % self.late_every == 0:
            outputs = state_at(self.late_s)
        if self.nan_every and count % self.nan_every == 0:
            outputs = {**outputs, "actual_q": (math.nan,) * 6}
        return outputs


def _fit(value, rtde_type: str):
    """A modelled value cut to the size of the type the controller says it has."""
    return tuple(value)[: wire.item_count(rtde_type)] if rtde_type.startswith("VECTOR") else value


@dataclass
class _Recipe:
    """An accepted output recipe: names, types, packing and send period (s)."""

    recipe_id: int
    names: list[str]
    types: list[str]
    fmt: object
    period_s: float


def robot_outputs(robot: RobotSource, t_s: float) -> dict[str, object]:
    """The modelled output fields ``t_s`` s into the program, in RTDE units (rad, rad/s)."""
    st = robot.state(t_s)
    q = tuple(math.radians(v) for v in st.q_deg)
    qd = tuple(math.radians(v) for v in st.qd_deg_s)
    return {
        "timestamp": t_s,
        "actual_q": q,
        "target_q": q,
        "actual_qd": qd,
        "target_qd": qd,
        "robot_mode": int(st.robot_mode),
        "safety_mode": SAFETY_NORMAL,
        "runtime_state": RUNTIME_PLAYING,
        "speed_scaling": 1.0,
        "target_speed_fraction": 1.0,
    }


class _Session:
    """One client connection: handshake requests, then streaming until pause or EOF."""

    def __init__(self, server: RtdeServer, conn: socket.socket):
        self.server = server
        self.conn = conn
        self.buffer = b""
        self.recipe: _Recipe | None = None
        self.next_recipe_id = 1
        self.streaming = False
        self.next_send = 0.0
        self.sent = 0
        self.inputs: dict[int, _Recipe] = {}  # accepted input recipes by id

    def run(self) -> None:
        """Serve until the client leaves or the server stops; socket errors end the session (and
        free the inputs it wrote)."""
        try:
            with contextlib.suppress(OSError), self.conn:
                while not self.server.stopping.is_set():
                    if not self._receive(self._wait_s()):
                        return  # EOF: the client hung up
                    if self.streaming and time.monotonic() >= self.next_send:
                        self._send_data()
        finally:
            self.server.release(self)

    def _wait_s(self) -> float:
        """How long to wait for client bytes: until the next data package, at most 0.1 s."""
        if not self.streaming:
            return 0.1
        return min(0.1, max(0.0, self.next_send - time.monotonic()))

    def _receive(self, timeout_s: float) -> bool:
        """Read and answer whatever requests arrived within ``timeout_s``; False on EOF."""
        ready, _, _ = select.select([self.conn], [], [], timeout_s)
        if not ready:
            return True
        chunk = self.conn.recv(65536)
        if not chunk:
            return False
        packages, self.buffer = wire.split(self.buffer + chunk)
        for package in packages:
            self._answer(package)
        return True

    def _answer(self, package: wire.Package) -> None:
        """Reply to one request (data and text packages from the client need no reply)."""
        kind = package.kind
        if chr(kind) == self.server.faults.stall_at:
            return  # a controller stuck in its handshake: the client waits for ever
        if kind == wire.REQUEST_PROTOCOL_VERSION:
            version = wire.parse_protocol_request(package.payload)
            self.conn.sendall(wire.bool_reply(kind, version == wire.PROTOCOL_VERSION))
        elif kind == wire.GET_URCONTROL_VERSION:
            v = self.server.version
            self.conn.sendall(wire.version_reply(v.major, v.minor, v.bugfix, v.build))
        elif kind == wire.SETUP_OUTPUTS:
            self.conn.sendall(self._setup_outputs(package.payload))
        elif kind == wire.SETUP_INPUTS:
            self.conn.sendall(self._setup_inputs(package.payload))
        elif kind == wire.DATA_PACKAGE:
            self._take_inputs(package.payload)
        elif kind == wire.START:
            started = self.recipe is not None
            self.streaming = started and self.server.faults.stall_at != "U"
            self.next_send = time.monotonic()
            self.conn.sendall(wire.bool_reply(kind, started))
        elif kind == wire.PAUSE:
            self.streaming = False
            self.conn.sendall(wire.bool_reply(kind, True))

    def _setup_outputs(self, payload: bytes) -> bytes:
        """Accept the recipe if every name is known; answer the types either way."""
        frequency, names = wire.parse_setup_outputs(payload)
        types = self.server.faults.recipe_types(names)
        recipe_id = self.next_recipe_id
        if wire.NOT_FOUND not in types and names:
            frequency = min(max(frequency, 1.0), MAX_FREQUENCY_HZ)
            self.recipe = _Recipe(recipe_id, names, types, wire.data_format(types), 1.0 / frequency)
            self.next_recipe_id += 1
        return wire.setup_outputs_reply(recipe_id, types)

    def _setup_inputs(self, payload: bytes) -> bytes:
        """Accept an input recipe whose every name this controller takes and no other connection
        writes; answer the types either way (recipe id 0: refused)."""
        names = wire.parse_setup_inputs(payload)
        types = self.server.claim(self, names, wire.input_types(names))
        if not names or wire.NOT_FOUND in types or wire.IN_USE in types:
            return wire.setup_inputs_reply(0, types)
        recipe_id = len(self.inputs) + 1
        self.inputs[recipe_id] = _Recipe(recipe_id, names, types, wire.data_format(types), 0.0)
        return wire.setup_inputs_reply(recipe_id, types)

    def _take_inputs(self, payload: bytes) -> None:
        """A client's data package: the inputs of its recipe, if it is one of exactly that size."""
        recipe = self.inputs.get(payload[0]) if payload else None
        if recipe is None or len(payload) != recipe.fmt.size:
            with self.server.input_errors.get_lock():
                self.server.input_errors.value += 1
            return
        _, values = wire.unpack_data(payload, recipe.fmt, recipe.types)
        self.server.set_inputs({name: values[k] for k, name in enumerate(recipe.names)})

    def _send_data(self) -> None:
        """Send the current state; if late by whole periods, skip them as the controller does."""
        recipe, now = self.recipe, time.monotonic()
        late = int((now - self.next_send) // recipe.period_s)
        if late:
            with self.server.skipped.get_lock():
                self.server.skipped.value += late
        scheduled = self.next_send + late * recipe.period_s
        self.next_send = scheduled + recipe.period_s
        faults, self.sent = self.server.faults, self.sent + 1
        if faults.garbage and self.sent == 1:
            self.conn.sendall(wire.pack(wire.DATA_PACKAGE, bytes([recipe.recipe_id]) + GARBAGE_PACKAGE))
            return
        outputs = faults.spoil(
            self.server.outputs(scheduled), self.sent, lambda ago: self.server.outputs(scheduled - ago)
        )
        values = [
            _fit(v, t)
            for v, t in zip(wire.values_for(recipe.names, recipe.types, outputs), recipe.types, strict=True)
        ]
        self.conn.sendall(wire.data_package(recipe.recipe_id, recipe.fmt, recipe.types, values))


class RtdeServer:
    """RTDE on ``(host, port)`` serving ``robot``; one thread per client connection.

    ``start_monotonic`` (``time.monotonic()`` value, shared by every process on the machine) is
    when the robot program started; simulated devices that share it agree on the robot's pose.
    """

    def __init__(
        self,
        robot: RobotSource,
        host: str,
        port: int = RTDE_PORT,
        *,
        start_monotonic: float | None = None,
        version: ControllerVersion = ControllerVersion(),
        skipped=None,
        faults: RtdeFaults = RtdeFaults(),
        inbox=None,
        input_errors=None,
    ):
        self.robot = robot
        self.faults = faults
        self.skipped = multiprocessing.Value("q", 0) if skipped is None else skipped
        self.input_errors = multiprocessing.Value("q", 0) if input_errors is None else input_errors
        self.inbox = inbox
        self.inputs: dict[str, object] = {}  # the last value written to each input
        self._owners: dict[str, _Session] = {}  # which connection writes each input
        self._inputs_lock = threading.Lock()
        self.version = version
        self.start_monotonic = time.monotonic() if start_monotonic is None else start_monotonic
        self.stopping = threading.Event()
        self.sessions: list[_Session] = []
        self.sock = socket.create_server((host, port))  # SO_REUSEADDR: rebinds at once
        self.address = self.sock.getsockname()[:2]

    def claim(self, session: _Session, names: list[str], types: list[str]) -> list[str]:
        """``types`` with ``IN_USE`` for inputs another connection writes; if none is, the
        inputs are ``session``'s from now on."""
        with self._inputs_lock:
            said = [
                wire.IN_USE if t != wire.NOT_FOUND and self._owners.get(n, session) is not session else t
                for n, t in zip(names, types, strict=True)
            ]
            if wire.IN_USE not in said and wire.NOT_FOUND not in said:
                self._owners.update(dict.fromkeys(names, session))
        return said

    def release(self, session: _Session) -> None:
        """A connection ended: its inputs are free for another (they keep their values)."""
        with self._inputs_lock:
            for name in [n for n, s in self._owners.items() if s is session]:
                del self._owners[name]

    def set_inputs(self, values: dict[str, object]) -> None:
        """Inputs a client wrote; writing the target index register (the index + 1; 0: none)
        hands the registered target to the program."""
        with self._inputs_lock:
            self.inputs.update(values)
            index = f"input_int_register_{TARGET_INDEX_INPUT}"
            if self.inbox is None or index not in values or int(values[index]) < 1:
                return
            q_deg = target_from_inputs(self.inputs)
        self.inbox(int(values[index]) - 1, q_deg)

    def outputs(self, at_monotonic: float) -> dict[str, object]:
        """Modelled output fields at monotonic time ``at_monotonic``."""
        return robot_outputs(self.robot, at_monotonic - self.start_monotonic)

    def serve(self, stop) -> None:
        """Accept clients until ``stop`` (a threading or multiprocessing Event) is set, then close
        every connection."""
        threads = []
        with self.sock:
            self.sock.settimeout(0.05)
            while not stop.is_set():
                try:
                    conn, _ = self.sock.accept()
                except TimeoutError:
                    continue
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                session = _Session(self, conn)
                self.sessions.append(session)
                threads.append(threading.Thread(target=session.run, daemon=True))
                threads[-1].start()
        self.stopping.set()
        for t in threads:
            t.join(timeout=1.0)


def _serve_in_child(
    robot, host, port, start_monotonic, version, skipped, ready, stop, faults, inbox, input_errors
) -> None:
    """Child-process entry: bind, report the address (or the bind error), serve until stopped."""
    try:
        server = RtdeServer(
            robot,
            host,
            port,
            start_monotonic=start_monotonic,
            version=version,
            skipped=skipped,
            faults=faults,
            inbox=inbox,
            input_errors=input_errors,
        )
    except OSError as exc:
        ready.send(("error", f"cannot bind RTDE server to {host}:{port}: {exc}"))
        return
    ready.send(("ok", server.address))
    server.serve(stop)


class RtdeServerProcess:
    """The RTDE server in a child process (spawned, so no locks or threads are inherited).

    Use as a context manager, or call :meth:`start` / :meth:`stop`. ``start`` returns once the
    server listens (or raises ``OSError`` naming the address); ``stop`` closes every connection
    (clients see EOF) and ends the process within ``timeout_s``. A stopped server can be started
    again on the same address: the controller coming back.
    """

    def __init__(
        self,
        robot: RobotSource,
        host: str = "127.0.0.1",
        port: int = RTDE_PORT,
        *,
        start_monotonic: float | None = None,
        version: ControllerVersion = ControllerVersion(),
        timeout_s: float = 10.0,
        faults: RtdeFaults = RtdeFaults(),
        inbox=None,
    ):
        self.robot = robot
        self.faults = faults
        self.inbox = inbox  # picklable: it goes to the child (sim_fixtures.target_channel.TargetInbox)
        self.host, self.port = host, port
        self.start_monotonic = time.monotonic() if start_monotonic is None else start_monotonic
        self.version = version
        self.timeout_s = timeout_s
        self._ctx = multiprocessing.get_context("spawn")
        self._skipped = self._ctx.Value("q", 0)
        self._input_errors = self._ctx.Value("q", 0)
        self._process = None
        self._stop = None

    @property
    def pid(self) -> int | None:
        """The child's process id while it runs (tests freeze it with SIGSTOP)."""
        return self._process.pid if self.running else None

    @property
    def skipped(self) -> int:
        """Data packages skipped because the server was late (all connections, all starts)."""
        return self._skipped.value

    @property
    def input_errors(self) -> int:
        """Client data packages dropped: no accepted input recipe of that id and size."""
        return self._input_errors.value

    @property
    def running(self) -> bool:
        """Whether the child process is alive."""
        return self._process is not None and self._process.is_alive()

    def start(self) -> RtdeServerProcess:
        """Spawn the server and wait until it listens."""
        if self.running:
            raise RuntimeError(f"RTDE server on {self.host}:{self.port} is already running")
        receiver, sender = self._ctx.Pipe(duplex=False)
        self._stop = self._ctx.Event()
        self._process = self._ctx.Process(
            target=_serve_in_child,
            daemon=True,
            name=f"rtde-sim-{self.host}",
            args=(
                self.robot,
                self.host,
                self.port,
                self.start_monotonic,
                self.version,
                self._skipped,
                sender,
                self._stop,
                self.faults,
                self.inbox,
                self._input_errors,
            ),
        )
        self._process.start()
        sender.close()
        if not receiver.poll(self.timeout_s):
            self.stop()
            raise OSError(f"RTDE server on {self.host}:{self.port} did not start within {self.timeout_s} s")
        status, detail = receiver.recv()
        receiver.close()
        if status != "ok":
            self.stop()
            raise OSError(detail)
        return self

    def stop(self) -> None:
        """Stop serving and end the child (terminate, then kill, if it does not exit)."""
        if self._process is None:
            return
        self._stop.set()
        self._process.join(self.timeout_s)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(1.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(1.0)
        self._process = None

    def __enter__(self) -> RtdeServerProcess:
        return self if self.running else self.start()

    def __exit__(self, *exc_info) -> None:
        self.stop()


def start_on_free_loopback(robot: RobotSource, *, attempts: int = 20, **kwargs) -> RtdeServerProcess:
    """Start a server on a random free address 127.0.0.2 .. 127.0.0.250 (port 30004 is fixed by
    ur_rtde, so parallel tests and benchmarks each take their own address)."""
    pick = random.SystemRandom()
    last = None
    for _ in range(attempts):
        server = RtdeServerProcess(robot, f"127.0.0.{pick.randint(2, 250)}", **kwargs)
        try:
            return server.start()
        except OSError as exc:
            last = exc
    raise OSError(f"no free loopback address for an RTDE server after {attempts} tries ({last})")
