"""Every simulated device of a station, composed from one station config (``station sim serve``).

One clock, one cell and one robot program feed all devices, so the drawstring and dial read what
the simulated true robot's pose implies at the instant they are asked:

- the robot program (:class:`~sim_fixtures.robot_program.SimRobot`) walks the cell's plan at the
  shared ``time_scale``; its RTDE controller runs in a child process on ``[robot] host``;
- the drawstring serves over the configured transport (Modbus TCP, Modbus RTU on a linked pty
  pair, or serial ASCII on a pty) and the dial on a pty at ``[dial] port``;
- instrument noise: the world's (:class:`~sim_fixtures.world.Noise`: drawstring 0.02 mm, dial
  0.002 mm, 1 um resolution), each from its own generator seeded by ``[sim] seed``;
- a slack cable (:meth:`SimStation.slacken`): the cable off the tool, the drawstring reading
  ``SLACK_MM`` (uniform) instead of the distance;
- a sweep plan (``plan`` with pass ids): the robot sweeps each pass along its true line
  (:mod:`sim_fixtures.sweep_program`); each sensor reports the world as it was its
  ``[sim] *_latency_s`` before it answers (plus Gaussian ``*_jitter_s``), leaves a fraction
  ``*_drop`` of requests unanswered (drawn from its own generator), and the dial lifts off the edge
  above ``liftoff_speed_mm_s`` or inside the ``lifted`` windows.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import functools
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

from drivers.ascii import DIALECTS
from drivers.config import DrawstringAscii, DrawstringModbusTcp, RobotOpcUa, RobotRos, RobotRtde
from errors import InputError
from sim_fixtures.controller import presented
from sim_fixtures.modbus_device import ModbusDevice
from sim_fixtures.opcua_server import OpcUaRobotServer, position_node, speed_node
from sim_fixtures.robot_program import RobotFault, SimRobot
from sim_fixtures.rosbridge_server import JOINT_NAMES, RosbridgeServer
from sim_fixtures.rtde_server import RtdeServerProcess, start_on_free_loopback
from sim_fixtures.serial_device import SerialAsciiDevice
from sim_fixtures.sources import CellSource, SimClock
from sim_fixtures.sweep_program import SweepRobot, pass_path
from sim_fixtures.target_channel import TargetChannel, TargetInbox
from sim_fixtures.unmodelled import KINDS, Unmodelled
from sim_fixtures.world import Placement, Robot, World

DIAL_RANGE_MM = (-12.5, 12.5)  # travel of a 25 mm indicator: outside it reads ERR3
PLAY_WAIT_S = 1e6  # a program run once waits this long (real s) at its first target for play
PLAY_POLL_S = 0.3  # real s: reads of the joints this long, none PLAY_GAP_S after the last, press play
PLAY_GAP_S = 0.25  # real s: a longer pause between reads is no session polling
PLAY_SUBSCRIBED_S = 3.0  # real s: a ROS subscription this long unbroken, press play (a session's is)
OPCUA_CYCLE_S = 0.016  # simulated s: the OPC UA server's samples to a subscription (a 62.5 Hz cycle)
SLACK_MM = (0.0, 20.0)  # a cable off the tool retracts into its housing: the sensor reads near zero


@dataclass(frozen=True)
class WorldCell:
    """The simulated world (true robot, anchor, gauge lines) with its plan: ``plan_deg`` (M, 6)
    true configurations whose TCPs touch the lines, ``plan_lines`` (M,) their line ids. A program
    that takes corrected targets (a rehearsal) has ``plan_targets`` (M,), the plan's target id of
    each: a corrected target names it (:class:`Retarget`)."""

    world: World
    plan_deg: np.ndarray
    plan_lines: np.ndarray
    plan_targets: np.ndarray | None = None

    def true_length_mm(self, q_deg) -> np.ndarray:
        return self.world.true_length_mm(q_deg)

    def true_dial_mm(self, q_deg, line_ids) -> np.ndarray:
        return self.world.true_dial_mm(q_deg, line_ids)


@functools.lru_cache(maxsize=4)
def make_cell(seed: int, targets_per_line: int = 70, unmodelled: Unmodelled | None = None) -> WorldCell:
    """The simulated cell of ``[sim] seed``: ``World.create(seed)`` (its true robot carrying
    ``unmodelled``, ``[sim] unmodelled``) and its plan along each line (the plan's IK is seeded by
    ``seed`` too, so every caller gets the same targets)."""
    world = dataclasses.replace(World.create(seed), unmodelled=unmodelled)
    q, lines = world.line_configurations(targets_per_line, np.random.default_rng([seed, 2]))
    return WorldCell(world, q, lines)


def planned_cell(
    seed: int, plan_deg: np.ndarray, plan_lines: np.ndarray, unmodelled: Unmodelled | None = None
) -> WorldCell:
    """The cell of ``[sim] seed`` (carrying ``unmodelled``) walking a designed plan (``station
    plan``): each planned pose moved onto its true line, as the robot program touches the edge near
    the planned pose."""
    world = dataclasses.replace(World.create(seed), unmodelled=unmodelled)
    q, lines = world.touch_lines(plan_deg, plan_lines, np.random.default_rng([seed, 5]))
    return WorldCell(world, q, lines)


def rehearsal_cell(
    nominal: Robot,
    placement: Placement,
    seed: int,
    plan: tuple[np.ndarray, np.ndarray] | None = None,
    targets_per_line: int = 70,
    targets: np.ndarray | None = None,
) -> WorldCell:
    """Your own cell rehearsed (``sim serve --robot R --setup S``): the true robot, anchor and lines
    drawn around ``nominal`` and ``placement`` (``World.around``), the robot program commanding the
    plan's joints, so the tool lands off the edge along the dial axis by the robot's error, as on a
    real robot (``World.land``). ``plan`` (configurations (M, 6) [deg], line ids (M,)): the plan's,
    ``targets`` (M,) its target ids (default 0 .. M-1); None: the nominal model's own
    ``targets_per_line`` contacts along each line of the placement. The program takes corrected
    targets (:class:`Retarget`)."""
    world = World.around(nominal, placement, seed)
    if plan is None:
        drawn = World(nominal, nominal, placement.anchor_mm, placement.length_offset_mm, placement.lines)
        plan = drawn.line_configurations(targets_per_line, np.random.default_rng([seed, 2]))
    lines = np.asarray(plan[1], int)
    q, reached = world.landing(np.asarray(plan[0], float).reshape(-1, 6), lines)
    ids = np.arange(len(lines)) if targets is None else np.asarray(targets, int)
    return WorldCell(world, q[reached], lines[reached], ids[reached])


def sweep_cell(
    seed: int, plan_deg, plan_lines, passes, unmodelled: Unmodelled | None = None
) -> tuple[WorldCell, list]:
    """The cell of ``[sim] seed`` (carrying ``unmodelled``) sweeping a sweep plan: each waypoint
    moved onto its true line as :func:`planned_cell` does (all rows kept, in plan order: a row the
    true robot cannot reach keeps its planned joints and is left out of its pass's path), and the
    dense path of every pass."""
    world = dataclasses.replace(World.create(seed), unmodelled=unmodelled)
    lines, passes = np.asarray(plan_lines, int), np.asarray(passes, int)
    rng = np.random.default_rng([seed, 5])
    q, reached = world.touch_lines(plan_deg, lines, rng, every=True)
    q = np.where(reached[:, None], q, np.asarray(plan_deg, float))
    paths = []
    for p in dict.fromkeys(passes.tolist()):
        rows = np.flatnonzero((passes == p) & reached)
        if len(rows):
            paths.append(pass_path(world.true, q[rows], rows))
    return WorldCell(world, q, lines), paths


def sweep_robot(cfg, paths: list, hold: bool = False) -> SweepRobot:
    """The sweeping program over ``paths`` (:func:`sweep_cell`'s) at the station config ``cfg``'s
    ``[sim]`` speeds, dwells and time scale."""
    sim = cfg.sim
    return SweepRobot(
        paths,
        speed_mm_s=sim.sweep_speed_mm_s,
        accel_mm_s2=sim.sweep_accel_mm_s2,
        speed_deg_s=sim.speed_deg_s,
        accel_deg_s2=sim.accel_deg_s2,
        dwell_s=sim.dwell_s,
        time_scale=cfg.time_scale,
        hold=hold,
    )


@dataclass(frozen=True)
class Retarget:
    """Where the rehearsed program really takes its target k (``SimRobot``'s ``retarget``): if the
    ``channel`` held corrected joints for that target (``cell.plan_targets[k]``) when the move began,
    where the true robot lands commanded to them (``World.land``: brought onto the true line, off
    it along the dial axis by what the correction left of the robot's miss); else None."""

    channel: TargetChannel
    cell: WorldCell

    def __call__(self, k: int, prog_s: float) -> np.ndarray | None:
        held = self.channel.at(prog_s)
        if held is None or held[0] != int(self.cell.plan_targets[k]):
            return None
        q, _ = self.cell.world.land(held[1][None], self.cell.plan_lines[k : k + 1])
        return q[0] if len(q) else None


def opcua_robot(
    section: RobotOpcUa,
    robot: SimRobot,
    clock: SimClock,
    play: bool = False,
    hand=None,
    time_scale: float = 1.0,
) -> OpcUaRobotServer:
    """The robot program's joints on an OPC UA server at the section's ``url``; the config's node
    ids must be the server's (``sim_fixtures.opcua_server``: the Robotics companion layout).
    ``play``: the program (waiting at home) starts once the station polls the joints steadily
    (:class:`PlayOnPoll`), as an operator presses play once the session waits for the robot (with a
    ``subscription_ms``, the server samples a subscribed client at ``OPCUA_CYCLE_S`` of simulated
    time (``time_scale`` simulated seconds a real one), each sample
    a read, play after ``PLAY_SUBSCRIBED_S`` of them, as a ROS subscription's).
    ``hand(target, q_deg)``: where corrected targets written to the server go (the program's channel)."""
    positions, speeds = section.nodes()
    if positions != [position_node(i) for i in range(1, 7)] or speeds not in (
        None,
        [speed_node(i) for i in range(1, 7)],
    ):
        raise InputError(
            f"[robot] position_node, speed_node: the simulated OPC UA server publishes {position_node(1)!r} "
            "(Axis1 .. Axis6) and ActualSpeed beside it: leave both at their defaults"
        )
    url = urlsplit(section.url)
    # a subscription's samples count as reads, as the ROS messages do
    operator = (
        PlayOnPoll(clock, PLAY_SUBSCRIBED_S if section.subscription_ms > 0 else PLAY_POLL_S) if play else None
    )

    def state():
        if operator is not None:
            operator.read()
        now = robot.state(clock.now())
        return now.q_deg, now.qd_deg_s

    sample_s = OPCUA_CYCLE_S / time_scale if section.subscription_ms > 0 else None
    return OpcUaRobotServer(state, url.hostname, url.port or 4840, hand, sample_s)


class PlayOnPoll:
    """The operator of a program run once: presses play (starts ``clock``) once the station has read
    the joints for ``PLAY_POLL_S`` with no pause over ``PLAY_GAP_S`` (a session polls them while it
    waits for the robot, a hundred times a second). A ``station read`` looks twice in one go and
    leaves: it does not start the program, however often it is run."""

    def __init__(self, clock: SimClock, poll_s: float = PLAY_POLL_S):
        self.clock, self.poll_s = clock, poll_s
        self._since = self._last = -float("inf")  # the present stretch of steady reads: its start, its last

    def read(self) -> None:
        """One read of a joint's value: play, if it completes a steady stretch."""
        if self.clock.now() >= 0:
            return
        now = time.monotonic()
        if now - self._last > PLAY_GAP_S:
            self._since = now
        self._last = now
        if now - self._since >= self.poll_s:
            self.clock.start_monotonic = now


def ros_robot(
    section: RobotRos, robot: SimRobot, clock: SimClock, play: bool = False, hand=None
) -> RosbridgeServer:
    """The robot program's joints as ``sensor_msgs/JointState`` on a rosbridge at the section's
    host and port; its ``joint_names`` must be the ones published (``JOINT_NAMES``). ``play``: as
    :func:`opcua_robot`'s, each message published to a subscriber a read, play after
    ``PLAY_SUBSCRIBED_S`` of them unbroken (a session subscribes as it opens its devices, seconds
    before it polls: a resumed one refits its samples first; a ``station read`` takes one message
    and leaves). ``hand(target, q_deg)``: where corrected targets published on its
    ``target_topic`` go (the program's channel)."""
    if list(section.joint_names) != list(JOINT_NAMES):
        raise InputError(
            f"[robot] joint_names: the simulated rosbridge publishes {list(JOINT_NAMES)}: name those"
        )
    operator = PlayOnPoll(clock, PLAY_SUBSCRIBED_S) if play else None

    def state():
        if operator is not None:
            operator.read()
        now = robot.state(clock.now())
        return now.q_deg, now.qd_deg_s

    return RosbridgeServer(
        state, section.host, section.port, section.topic, target_topic=section.target_topic, hand=hand
    )


def _pty_link(port: str, section: str, elsewhere: Path | None = None) -> Path:
    """A pty link path from the config; refuses to replace anything that is not a symlink. With
    ``elsewhere``, a link that is live (another cell's pty) is left alone: the link goes there."""
    path = Path(port)
    if elsewhere is not None and path.exists():
        return elsewhere / path.name
    if path.exists() and not path.is_symlink():
        raise InputError(
            f"[{section}] port = {port!r}: exists and is not a link; "
            "sim serve only creates pty links (e.g. /tmp/station-sim/<name>)"
        )
    return path


@contextlib.contextmanager
def _links_claimed(cfg, elsewhere: Path | None):
    """While held, no other cell started ``elsewhere`` looks for or makes pty links in the
    configured links' folders (an flock on ``.links.lock`` in each): a link found free is ours."""
    if elsewhere is None:
        yield
        return
    ports = [
        s.port
        for s in (cfg.drawstring, cfg.dial)
        if s is not None and isinstance(getattr(s, "port", None), str)
    ]
    with contextlib.ExitStack() as stack:
        for folder in sorted({Path(p).parent for p in ports}):
            folder.mkdir(parents=True, exist_ok=True)
            fh = stack.enter_context(open(folder / ".links.lock", "a"))
            fcntl.flock(fh, fcntl.LOCK_EX)
        yield


class SimStation:
    """The simulated devices of a station configuration ``cfg`` (its device sections from
    ``drivers.config``, ``time_scale`` and ``sim``: seed and robot motion); ``start()`` returns one
    address dict per device and ``stop()`` ends them all (safe after a partial start).
    ``plan_deg``/``plan_lines`` are the targets the simulated robot walks; it waits ``start_delay_s``
    (real s) still at the first before it runs (an operator presses play once the station listens).
    ``cell``: another cell than the JR680 of ``[sim] seed`` (``rehearsal_cell``), ``plan`` unused;
    ``once``: the program runs the plan once, as a real one does, instead of round and round, from
    when a session polls an OPC UA robot (:class:`PlayOnPoll`; an RTDE robot's starts at once). ``convention``
    (joint_sign (6,), joint_offset_deg (6,) [deg]; None: the identity): the controller's, in which
    the robot's joints are published and its target channel's writes taken
    (:mod:`sim_fixtures.controller`); the truth walks the model's. ``plan`` with a third member,
    the pass id of each row (``station.formats.plan``'s ``sweep_pass``): the robot sweeps
    (:func:`sweep_cell`); ``lifted``: (start, end) windows [simulated s into every cycle of the
    program] in which the dial is off the edge. ``served`` keeps each sensor's fault plan and
    request count from :meth:`stop` on (what the simulator dropped, for tests)."""

    def __init__(
        self,
        cfg,
        hold: bool = False,
        faults: Sequence[RobotFault] = (),
        plan: tuple[np.ndarray, ...] | None = None,
        start_delay_s: float = 0.0,
        cell: WorldCell | None = None,
        once: bool = False,
        convention: tuple[Sequence[float], Sequence[float]] | None = None,
        lifted: Sequence[tuple[float, float]] = (),
    ):
        if not isinstance(cfg.robot, RobotRtde | RobotOpcUa | RobotRos):
            raise InputError(
                f"[robot] kind = {cfg.robot.kind!r}: sim serve simulates an RTDE controller "
                '(kind = "rtde"), an OPC UA server (kind = "opcua") or a rosbridge (kind = "ros")'
            )
        self.cfg = cfg
        self.once = once
        self.clock = SimClock(time.monotonic() + (PLAY_WAIT_S if once else start_delay_s))
        unmodelled = KINDS[cfg.sim.unmodelled]
        paths = None
        if cell is None and plan is None:
            cell = make_cell(cfg.sim.seed, cfg.sim.targets_per_line, unmodelled)
        elif cell is None and len(plan) > 2 and plan[2] is not None:
            cell, paths = sweep_cell(cfg.sim.seed, *plan, unmodelled)
        elif cell is None:
            cell = planned_cell(cfg.sim.seed, *plan[:2], unmodelled)
        if cfg.sim.change:  # the robot changed after the plan was taught (a bent link)
            cell = dataclasses.replace(cell, world=cell.world.changed(cfg.sim.change))
        # a program that takes corrected targets reads them from this channel (the JR680's walks its own)
        self.channel = None if cell.plan_targets is None else TargetChannel()
        self.robot = (
            self._sweeper(paths, hold)
            if paths is not None
            else SimRobot(
                cell.plan_deg,
                speed_deg_s=cfg.sim.speed_deg_s,
                accel_deg_s2=cfg.sim.accel_deg_s2,
                dwell_s=cfg.sim.dwell_s,
                hold=hold,
                time_scale=cfg.time_scale,
                faults=faults,
                rng=np.random.default_rng([cfg.sim.seed, 3]),
                once=once,
                retarget=None if self.channel is None else Retarget(self.channel, cell),
            )
        )
        self.inbox = None if self.channel is None else TargetInbox(self.channel, self.robot, self.clock)
        # what the controller publishes and takes: its own joint convention
        self.published, self.published_inbox = presented(self.robot, self.inbox, *(convention or ()))
        self.plan_deg, self.plan_lines = cell.plan_deg, cell.plan_lines
        self.source = CellSource(self.robot, cell, cfg.sim.liftoff_speed_mm_s, tuple(lifted))
        rngs = [np.random.default_rng([cfg.sim.seed, k]) for k in (0, 1, 6, 7, 8, 9)]
        self._length = cell.world.noise.drawstring(rngs[0])
        self._dial = cell.world.noise.dial(rngs[1])
        self._slack_rng, self._slack_until, self.slack_read = rngs[2], 0.0, 0
        self._lag_rng, self._drop_rngs = rngs[3], {"drawstring": rngs[4], "dial": rngs[5]}
        self._lag_lock = threading.Lock()
        self.devices: dict[str, object] = {}
        self.served: dict[str, tuple] = {}

    def _sweeper(self, paths, hold: bool) -> SweepRobot:
        return sweep_robot(self.cfg, paths, hold)

    def _measured_at(self, latency_s: float, jitter_s: float) -> float:
        """The real time [s since start] whose world a sensor of that latency and jitter
        (simulated s) reports now."""
        with self._lag_lock:  # the devices' threads share the generator
            lag = latency_s + (self._lag_rng.normal(0.0, jitter_s) if jitter_s > 0 else 0.0)
        return self.clock.now() - max(lag, 0.0) / self.cfg.time_scale

    def _drops(self, name: str, device) -> object:
        """``device`` with its fault plan leaving ``[sim] <name>_drop`` of the requests unanswered."""
        fraction = getattr(self.cfg.sim, f"{name}_drop")
        if fraction > 0:
            device.faults.drop(fraction, self._drop_rngs[name])
        return device

    def slacken(self, seconds: float) -> None:
        """The cable comes off the tool for ``seconds`` (real): the drawstring reads ``SLACK_MM``;
        ``slack_read`` counts the readings given meanwhile (reset here)."""
        self._slack_until = time.monotonic() + seconds
        self.slack_read = 0

    def measure_length(self) -> float:
        if time.monotonic() < self._slack_until:
            self.slack_read += 1
            return self._length.measure(self._slack_rng.uniform(*SLACK_MM))
        at = self._measured_at(self.cfg.sim.drawstring_latency_s, self.cfg.sim.drawstring_jitter_s)
        return self._length.measure(self.source.state(at).length_mm)

    def measure_dial(self) -> float:
        at = self._measured_at(self.cfg.sim.dial_latency_s, self.cfg.sim.dial_jitter_s)
        return self._dial.measure(self.source.state(at).dial_mm)

    def _drawstring(self, elsewhere: Path | None = None, tcp_port: int | None = None):
        ds = self.cfg.drawstring
        if isinstance(ds, DrawstringAscii):
            link = _pty_link(ds.port, "drawstring", elsewhere)
            return self._drops(
                "drawstring", SerialAsciiDevice(link, DIALECTS["drawstring"], self.measure_length)
            )
        regs = ds.registers.register_map(ds.device_id)
        if isinstance(ds, DrawstringModbusTcp):
            return self._drops(
                "drawstring",
                ModbusDevice(
                    regs, self.measure_length, tcp=(ds.host, ds.port if tcp_port is None else tcp_port)
                ),
            )
        link = _pty_link(ds.port, "drawstring", elsewhere)
        return self._drops(
            "drawstring", ModbusDevice(regs, self.measure_length, rtu_link=link, baudrate=ds.baudrate)
        )

    def start(self, elsewhere: Path | None = None) -> list[dict]:
        """Serve every device; the addresses served, one dict each. With ``elsewhere`` (a folder),
        a device whose configured address another cell holds is served at a free one instead
        (RTDE on another 127.0.0.x, Modbus TCP on a free port, a pty link in ``elsewhere``): each
        is bound first and then announced, so cells started together never collide."""
        try:
            robot = self.cfg.robot
            if isinstance(robot, RobotOpcUa):
                self.devices["robot"] = opcua_robot(
                    robot, self.published, self.clock, self.once, self.published_inbox, self.cfg.time_scale
                ).start()
            elif isinstance(robot, RobotRos):
                self.devices["robot"] = ros_robot(
                    robot, self.published, self.clock, self.once, self.published_inbox
                ).start()
            else:
                self.devices["robot"] = self._rtde(elsewhere is not None)
            with _links_claimed(self.cfg, elsewhere):
                self.devices["drawstring"] = self._drawstring(elsewhere)
                try:
                    self.devices["drawstring"].start()
                except (OSError, RuntimeError):  # its TCP port taken: bind a free one
                    if elsewhere is None or not isinstance(self.cfg.drawstring, DrawstringModbusTcp):
                        raise
                    self.devices["drawstring"] = self._drawstring(tcp_port=0)
                    self.devices["drawstring"].start()
                if self.cfg.dial:
                    link = _pty_link(self.cfg.dial.port, "dial", elsewhere)
                    self.devices["dial"] = self._drops(
                        "dial",
                        SerialAsciiDevice(
                            link, DIALECTS[self.cfg.dial.dialect], self.measure_dial, DIAL_RANGE_MM
                        ),
                    )
                    self.devices["dial"].start()
        except BaseException:
            self.stop()
            raise
        return [self.address(name) for name in self.devices]

    def _rtde(self, elsewhere: bool) -> RtdeServerProcess:
        """The RTDE server at the configured host (port 30004 is fixed), or at a free loopback
        address where ``elsewhere`` and the configured one is taken."""
        started = self.clock.start_monotonic
        try:
            return RtdeServerProcess(
                self.published, self.cfg.robot.host, start_monotonic=started, inbox=self.published_inbox
            ).start()
        except OSError:
            if not elsewhere:
                raise
            return start_on_free_loopback(self.published, start_monotonic=started, inbox=self.published_inbox)

    def address(self, name: str) -> dict:
        """Where device ``name`` is served, as printed by ``sim serve``."""
        dev = self.devices[name]
        if isinstance(dev, RtdeServerProcess):
            return {
                "device": name,
                "protocol": "rtde",
                "host": dev.host,
                "port": dev.port,
                "frequency_hz": self.cfg.robot.frequency_hz,
                "time_scale": self.cfg.time_scale,
            }
        if isinstance(dev, ModbusDevice):
            return {"device": name, **dev.address}
        if isinstance(dev, RosbridgeServer):
            return {"device": name, "protocol": "rosbridge", "url": dev.url, "topic": dev.topic}
        if isinstance(dev, OpcUaRobotServer):
            return {"device": name, "protocol": "opcua", "url": dev.url, "time_scale": self.cfg.time_scale}
        return {
            "device": name,
            "protocol": "serial-ascii",
            "port": str(dev.port.link),
            "pty": dev.port.path,
            "dialect": next(k for k, v in DIALECTS.items() if v is dev.dialect),
        }

    def stop(self) -> None:
        sensors = {n: d for n, d in self.devices.items() if n != "robot"}
        self.served.update({n: (d.faults, d.requests) for n, d in sensors.items()})
        for dev in reversed(list(self.devices.values())):
            dev.stop()
        self.devices.clear()
