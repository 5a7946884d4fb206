"""``station sim serve [--config F] [--hold] [--plan P.csv | --program P] [--time-scale S]
[--robot R --setup S] [--seed N]``: run the simulated devices until SIGINT/SIGTERM.

Without ``--robot`` it simulates the shipped HSR-JR680 cell, whose robot program moves every
target onto its true line; with ``--robot R --setup S`` it rehearses your own cell
(``station.jobs.rehearsal``): that robot with random errors, that setup's drawstring and lines, the
program commanding the plan's nominal joints, so the tool lands off the edge by the robot's error;
a sweep plan (``--plan`` with a ``pass`` column) is swept pass by pass
(``sim_fixtures.sweep_program``), on the JR680 cell only;
joints over OPC UA: the program runs the plan once, from when a session polls the robot (a
``station read`` does not start it). ``--program``: the simulated controller runs a program
``station program`` wrote (any format; a sweep program's passes swept, on the JR680 cell only), its
joints read in the controller's convention; over OPC UA and ROS once, from when a session polls the
robot.

Publishes the plan its robot walks at ``[sim] plan_csv`` (where ``station sample`` looks by
default) and announces its robot and time scale beside it (``station.formats.announcement``: a
``station sample`` on that robot adopts the time scale), prints one JSON line per device with its
address (the robot's with the time scale), then serves; on a signal it stops every device, removes
the pty links and its announcement.
"""

from __future__ import annotations

import json
import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING

import configs
from errors import DeviceError, InputError
from station.commands.flags import seed

JR680_NAME = "HSR-JR680"
"""The robot ``sim serve`` simulates without ``--robot``: ``configs/robots/hsr_jr680.toml``'s name."""

if TYPE_CHECKING:
    import numpy as np

    from sim_fixtures.station_sim import WorldCell
    from sim_fixtures.world import Placement, Robot
    from station.formats.plan import Plan
    from station.formats.tables import RobotFile, SetupFile


def register(subparsers) -> None:
    sim = subparsers.add_parser("sim", help="simulated devices")
    actions = sim.add_subparsers(dest="action", required=True, metavar="ACTION")
    serve = actions.add_parser("serve", help="serve the simulated devices until interrupted")
    serve.add_argument(
        "--config",
        default=str(configs.path("station.toml")),
        help="station config (default: the shipped one, contract addresses)",
    )
    serve.add_argument(
        "--hold", action="store_true", help="keep the simulated robot still at its first target"
    )
    serve.add_argument(
        "--plan", type=Path, help="plan CSV (station plan) for the simulated robot to walk instead of its own"
    )
    serve.add_argument(
        "--program",
        type=Path,
        help="a measurement program (station program: .script, .csv, .src with its .dat, .mod, .ls) for the "
        "simulated controller to run instead: its contact points, in its order, in the controller's joints",
    )
    serve.add_argument(
        "--time-scale",
        type=float,
        metavar="S",
        help="simulated seconds per real second (default: the config's time_scale, 1 = real time; "
        "20: a 210-target session in about a minute); `station sample` adopts it",
    )
    serve.add_argument(
        "--robot", type=Path, help="rehearse your own cell: simulate this robot file (with --setup)"
    )
    serve.add_argument(
        "--setup", type=Path, help="the cell's setup TOML (drawstring, [[lines]] with point_mm, direction)"
    )
    serve.add_argument(
        "--seed", type=seed, help="seed of the simulated truth and noise (default: [sim] seed)"
    )
    serve.set_defaults(func=run)


def run(args) -> int:
    from sim_fixtures.station_sim import SimStation
    from station.config import load_station_config
    from station.formats.announcement import withdraw
    from station.formats.plan import Plan, load_plan

    cfg = load_station_config(args.config).with_time_scale(args.time_scale)
    if args.seed is not None:
        cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"seed": args.seed})})
    stop = threading.Event()
    plan = load_plan(args.plan) if args.plan else None
    if args.program is not None:
        if plan is not None:
            raise InputError("--plan or --program: the simulated robot walks one of them")
        plan = program_plan(args.program, cfg.sim.convention(_controller(args)))
    joints = None if plan is None else (plan.q_deg, plan.line)
    model, cell, controller = _rehearsal(args, cfg, joints, None if plan is None else plan.target)
    if plan is not None and plan.is_sweep:
        if cell is not None:
            raise InputError(
                "--plan: a sweep plan (with passes) plays on the simulated JR680 cell, not with --robot"
            )
        joints = (plan.q_deg, plan.line, plan.sweep_pass)  # the simulated robot sweeps its passes
    # a program run once, started when a session polls the robot: OPC UA's, and a written program over ROS
    once = cell is not None and (
        cfg.robot.kind == "opcua" or (args.program is not None and cfg.robot.kind == "ros")
    )
    convention = cfg.sim.convention(controller)
    station = SimStation(cfg, hold=args.hold, plan=joints, cell=cell, once=once, convention=convention)
    # Children start with Ctrl-C ignored (a terminal sends it to the whole process group): this
    # process alone handles it and stops them.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        addresses = station.start()
    except (OSError, RuntimeError) as exc:  # another simulator holds the addresses: leave its plan be
        station.stop()
        raise DeviceError(f"cannot start the simulated devices: {exc}") from exc
    publish_plan(Path(cfg.sim.plan_csv), plan or Plan.of(station.plan_deg, station.plan_lines))
    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda *_: stop.set())
        _announce(cfg, model)
        for address in addresses:
            print(json.dumps(address), flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        withdraw(cfg.sim.plan_csv)
        station.stop()
    return 0


def _rehearsal(args, cfg, joints, targets):
    """The robot model's name, the cell to simulate and the controller's joint convention (the
    robot file's ``[controller]``): with ``--robot``/``--setup`` the user's own
    (``station.jobs.rehearsal``; ``targets``: the plan's target ids), else the shipped JR680's (cell
    and convention None)."""
    if args.robot is None and args.setup is None:
        return JR680_NAME, None, None
    if args.robot is None or args.setup is None:
        raise InputError(
            "--robot and --setup go together: the robot file and the setup of the cell to rehearse"
        )
    from station.formats.tables import load_robot, load_setup

    robot, setup = load_robot(args.robot), load_setup(args.setup)
    cell = rehearsed_cell(
        robot, setup, str(args.setup), cfg.sim.seed, joints, cfg.sim.targets_per_line, targets
    )
    return robot.name, cell, robot.controller


def _controller(args):
    """The ``--robot`` file's ``[controller]`` (None without one)."""
    from station.formats.tables import load_robot

    return None if args.robot is None else load_robot(args.robot).controller


def program_plan(path: Path, convention: tuple[list[float], list[float]]) -> Plan:
    """The targets a program file walks (the format its extension names), their joints read by a
    controller of ``convention`` (``joint_sign``, ``joint_offset_deg``) as the model's."""
    import numpy as np

    from calib.conventions import model_joints
    from sim_fixtures.programs import read_program, read_sweep
    from station.formats.plan import Plan
    from station.jobs.programs import FORMATS

    by_extension = {f.extension: name for name, f in FORMATS.items()}
    fmt = by_extension.get(path.suffix.lower())
    if fmt is None:
        known = ", ".join(by_extension)
        raise InputError(f"--program {path}: not a program station program writes ({known})")
    try:
        passes = read_sweep(path, fmt)
        points = [] if passes else read_program(path, fmt)
    except FileNotFoundError as exc:
        raise InputError(f"--program {path}: no such file {exc.filename}") from None
    except (OSError, UnicodeDecodeError, ValueError, KeyError, IndexError) as exc:
        why = f"not a {fmt} program as station program writes it: {exc}"
        raise InputError(f"--program {path}: {why}") from None
    if passes:  # the waypoints of each pass, swept in order

        def each(value):
            return np.concatenate([np.broadcast_to(value(p), len(p.targets)) for p in passes])

        q = model_joints(np.concatenate([p.waypoints_deg for p in passes]), *convention)
        return Plan(each(lambda p: p.targets), each(lambda p: p.line), q, sweep_pass=each(lambda p: p.number))
    if not points:
        raise InputError(f"--program {path}: no measured targets in it")
    q = model_joints(np.array([p.contact_deg for p in points]), *convention)
    return Plan(np.array([p.target for p in points]), np.array([p.line for p in points]), q)


def _announce(cfg, model: str) -> None:
    """Say beside the published plan which robot this simulator serves (where, and which model), at
    which time scale."""
    from station.formats.announcement import announce

    try:
        announce(cfg.sim.plan_csv, cfg.robot.endpoint(), cfg.time_scale, model)
    except OSError as exc:
        raise DeviceError(
            f"cannot announce the simulator beside {cfg.sim.plan_csv}: {exc.strerror or exc}"
        ) from exc


def publish_plan(path: Path, plan: Plan) -> None:
    """Write the plan the simulated robot walks where ``station sample`` finds it by default."""
    from station.formats.base import atomic_write

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, plan.csv_text())
    except OSError as exc:
        raise DeviceError(f"cannot publish the simulated plan at {path}: {exc.strerror or exc}") from exc


# -- your own cell rehearsed (--robot R --setup S) ----------------------------------------------
# The robot file and setup a person wrote for a real cell become the simulator's nominal robot and
# placement; the truth is drawn around them (``World.around``) and the program walks the plan's
# joints as commanded, so the tool lands off the edge by the robot's error, as a real robot's does.
LINE_PLACEMENT_MM = 0.5
"""How far (1 sigma per axis) a true gauge edge lies from where the setup puts it: a block set
against a scribed mark, its edge measured with a caliper."""


def placement(setup: SetupFile, where: str) -> Placement:
    """The cell as the setup describes it: its drawstring and every ``[[lines]]`` entry (each with
    ``point_mm``, ``direction`` and an approach or dial axis, as ``station plan`` needs them)."""
    import numpy as np

    from sim_fixtures.world import GaugeLine, Placement
    from station.jobs.planning import placements

    if setup.drawstring is None:
        raise InputError(f"{where}: missing table [drawstring]: the simulator needs the cable's exit point")
    axis_default = None if setup.dial is None else setup.dial.axis
    lines = []
    for ln in setup.lines:
        point, direction, length, approach = placements(setup, where)[ln.id]
        dial = np.asarray(ln.dial_axis or axis_default or -approach, float)
        dial = dial - (dial @ direction) * direction  # the indicator reads across the edge
        lines.append(GaugeLine(ln.id, point, direction, length, dial / np.linalg.norm(dial), approach))
    return Placement(
        np.asarray(setup.drawstring.anchor_mm, float),
        setup.drawstring.length_offset_mm,
        tuple(lines),
        LINE_PLACEMENT_MM,
    )


def nominal_robot(robot: RobotFile) -> Robot:
    """The simulator's nominal robot: the file's table (standard D-H), TCP and joint limits."""
    import numpy as np

    from sim_fixtures.world import Robot

    return Robot(robot.table_deg(), np.asarray(robot.tool_mm, float), robot.limits_deg())


def rehearsed_cell(
    robot: RobotFile,
    setup: SetupFile,
    where: str,
    seed: int,
    plan: tuple[np.ndarray, np.ndarray] | None,
    targets_per_line: int,
    targets: np.ndarray | None = None,
) -> WorldCell:
    """The rehearsed cell of ``robot`` and ``setup`` (``where`` names the setup in messages); the
    simulated program walks ``plan`` (configurations [deg], line ids; ``targets`` its target ids)
    or, None, the nominal model's contacts along each line."""
    import numpy as np

    from sim_fixtures.station_sim import rehearsal_cell

    cell_placement = placement(setup, where)
    if plan is not None:
        unknown = sorted(set(np.asarray(plan[1]).tolist()) - {ln.id for ln in cell_placement.lines})
        if unknown:
            raise InputError(f"--plan: line {unknown[0]} is not among {where}'s [[lines]]")
    try:
        return rehearsal_cell(nominal_robot(robot), cell_placement, seed, plan, targets_per_line, targets)
    except RuntimeError as exc:  # a gauge line out of the nominal robot's reach
        raise InputError(f"{where}: {exc}") from None
