"""``station plan``: choose the configurations to measure before measuring (MCS on candidates)."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from errors import InputError
from station.commands.flags import number, parameters_as_flags, seed

_positive = number(int, "a whole number", lambda v: v >= 1, "{} must be at least 1")
_tilt = number(float, "a number of degrees", lambda v: 0 <= v < 90, "{} must be from 0 to below 90 deg")
_roll = number(float, "a number of degrees", lambda v: 0 <= v <= 180, "{} must be from 0 to 180 deg")

FLAGS = {"per_line": "--per-line", "n_select": "--select"}
"""The flag that sets each parameter of the plan design."""


def register(sub) -> None:
    p = sub.add_parser("plan", help="choose the configurations to measure along the setup's gauge lines")
    p.add_argument("session", type=Path, nargs="?", help="a session folder: its robot table and setup")
    p.add_argument("--robot", type=Path, help="robot model TOML (required without a session)")
    p.add_argument("--setup", type=Path, help="setup TOML with each line's point_mm/direction (ditto)")
    p.add_argument("--out", type=Path, required=True, help="plan CSV to write (what station sample follows)")
    p.add_argument("--per-line", type=_positive, default=100, help="candidate points per line (default 100)")
    p.add_argument(
        "--select", type=_positive, metavar="N", help="configurations to keep (default: where O1 flattens)"
    )
    p.add_argument(
        "--readings",
        type=_positive,
        metavar="K",
        help="readings averaged per capture, for the promise (default: the session's or the shipped "
        "station config's [session] readings, 5)",
    )
    p.add_argument(
        "--verify",
        type=_positive,
        nargs="?",
        const=15,
        metavar="N",
        help="a short verification plan instead (station verify): N poses (default 15) on one gauge line, "
        "those most sensitive to joint zeros and link lengths and twists",
    )
    p.add_argument(
        "--near",
        type=Path,
        metavar="PROGRAM.csv",
        help="add gauge-line contacts near this program's poses (q1_deg..q6_deg per row, the "
        "controller's joints, as station compensate's), so the residual map is learnt where it works",
    )
    p.add_argument("--near-poses", type=_positive, metavar="N", help="contacts --near adds (default 60)")
    p.add_argument(
        "--sweep",
        type=_positive,
        nargs="?",
        const=1,
        metavar="N",
        help="a sweep plan instead: N continuous passes (default 1) along each gauge line, the tool kept on "
        "the edge and turned as it slides (station program writes them as blended linear moves)",
    )
    p.add_argument(
        "--extra-passes",
        type=_positive,
        metavar="K",
        help="with --sweep: K passes more, each on the line where it promises most (default none)",
    )
    p.add_argument(
        "--max-tilt",
        type=_tilt,
        metavar="DEG",
        help="with --sweep: the most the tool tilts from the line's approach along a pass (default 45; "
        "less for a tool that cannot lean so far on the edge)",
    )
    p.add_argument(
        "--max-roll",
        type=_roll,
        metavar="DEG",
        help="with --sweep: the most the tool rolls about its axis from a pass's start (default 90)",
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--no-suggest", action="store_true", help="skip the search for a next line placement")
    p.add_argument("--report", type=Path, help="plan report JSON to write")
    p.add_argument("--plot", type=Path, help="PNG to write: O1 curve and line placements")
    p.set_defaults(func=run)


def run(args) -> int:
    from station.formats.base import Output, check_writable, write_outputs
    from station.jobs import planning

    if args.extra_passes and not args.sweep:
        raise InputError("--extra-passes: only with --sweep (it adds passes to a sweep plan)")
    for value, flag in ((args.max_tilt, "--max-tilt"), (args.max_roll, "--max-roll")):
        if value is not None and not args.sweep:
            raise InputError(f"{flag}: only with --sweep (it shapes a sweep's passes)")
    if args.sweep and args.near is not None:
        raise InputError("--near and --sweep: choose one (a sweep's passes run the whole edge)")
    for path, flag in ((args.out, "--out"), (args.report, "--report"), (args.plot, "--plot")):
        if path:
            check_writable(path, flag)
    robot, setup, where = _inputs(args)
    robot_where = str(args.robot) if args.robot else f"{args.session / 'session.toml'} [robot]"
    if args.verify:
        design = planning.verify_design(
            robot, setup, where, n_select=args.verify, seed=args.seed, robot_where=robot_where
        )
        write_outputs([Output.text(args.out, "--out", design.plan.csv_text())])
        print(
            f"verification plan: {len(design.plan)} poses on gauge line {design.report['line']}, chosen "
            f"to see joint zeros and link lengths and twists -> {args.out} (measure, then station verify)"
        )
        return 0
    if args.sweep:
        return _sweep(args, robot, setup, where)
    with parameters_as_flags(FLAGS):
        design = _design(args, robot, setup, where)(
            per_line=args.per_line,
            n_select=args.select,
            seed=args.seed,
            suggest=not args.no_suggest,
            readings=_readings(args),
            robot_where=robot_where,
            progress=lambda message: print(f"... {message}", file=sys.stderr, flush=True),
        )
    outputs = [Output.text(args.out, "--out", design.plan.csv_text())]
    if args.report:
        outputs.append(Output.text(args.report, "--report", json.dumps(design.report, indent=2) + "\n"))
    if args.plot:
        from station.view.plots import plan_figure

        outputs.append(Output(args.plot, "--plot", lambda tmp: plan_figure(design.report, tmp)))
    write_outputs(outputs)
    print(planning.summary(design))
    print("wrote " + ", ".join(str(o.path) for o in outputs))
    return 0


def _design(args, robot, setup, where):
    """``planning.design`` on the robot and setup, or with ``--near`` ``near_planning.near_design`` on the
    program's poses too (read in the controller's joints, converted by the robot file's
    ``[controller]``), awaiting ``design``'s options."""
    import functools

    from station.formats.program import load_program
    from station.jobs import near_planning, planning

    if args.near is None:
        return functools.partial(planning.design, robot, setup, where)
    program = load_program(args.near)
    q_model = robot.controller.model_deg(program.q_deg)
    given = {} if args.near_poses is None else {"n_near": args.near_poses}
    return functools.partial(
        near_planning.near_design, robot, setup, q_model, where, program_where=str(args.near), **given
    )


def _sweep(args, robot, setup, where) -> int:
    """``--sweep``: the passes, the plan CSV and (``--report``) its report."""
    from station.formats.base import Output, write_outputs
    from station.jobs import sweeping

    turns = {"max_tilt_deg": args.max_tilt, "max_roll_deg": args.max_roll}
    shape = dataclasses.replace(sweeping.SHAPE, **{k: v for k, v in turns.items() if v is not None})
    design = sweeping.sweep_design(
        robot, setup, where, passes=args.sweep, extra=args.extra_passes or 0, seed=args.seed, shape=shape
    )
    outputs = [Output.text(args.out, "--out", design.plan.csv_text())]
    if args.report:
        outputs.append(Output.text(args.report, "--report", json.dumps(design.report, indent=2) + "\n"))
    write_outputs(outputs)
    print(sweeping.sweep_summary(design))
    print("wrote " + ", ".join(str(o.path) for o in outputs))
    return 0


def _inputs(args):
    """Robot table, setup and the setup's name for messages: the session's, the flags overriding."""
    from station.formats.session_folder import load_robot_and_setup

    robot, setup, where, _ = load_robot_and_setup(args.session, args.robot, args.setup)
    if robot is None or setup is None:
        raise InputError("station plan needs --robot and --setup (or a session folder)")
    return robot, setup, where


def _readings(args) -> int:
    """``--readings``, else ``[session] readings`` of the session's station config, else of the
    shipped one: what a capture will average."""
    import configs
    from station.config import load_station_config, station_config
    from station.formats.base import read_toml

    if args.readings is not None:
        return args.readings
    if args.session is not None:
        where = args.session / "session.toml"
        station = read_toml(where).get("station")
        if station is not None:
            return station_config(station, f"{where} [station]").session.readings
    return load_station_config(configs.path("station.toml")).session.readings
