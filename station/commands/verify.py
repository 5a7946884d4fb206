"""``station verify``: is a corrected table still right? Judged on samples it never saw."""

from __future__ import annotations

import json
from pathlib import Path

from errors import InputError
from station.commands.flags import parameters_as_flags

FLAGS = {"setup": "--setup"}
EXIT_DRIFTED = 3


def register(sub) -> None:
    p = sub.add_parser(
        "verify",
        help="judge a corrected table on new samples: holds (exit 0) or drifted (exit 3)",
    )
    p.add_argument(
        "samples", type=Path, help="samples CSV (drawstring or tracker positions) or a session folder"
    )
    p.add_argument("--table", type=Path, required=True, help="the corrected table TOML to judge")
    p.add_argument(
        "--robot",
        type=Path,
        help="the robot's nominal model TOML: must be the table's robot; its serial names it",
    )
    p.add_argument("--setup", type=Path, help="setup TOML (required for a drawstring CSV)")
    p.add_argument("--report", type=Path, help="V.json to write")
    p.add_argument("--plot", type=Path, help="PNG to write: error per sample and per line, the verdict")
    add_history_flags(p)
    p.set_defaults(func=run)


def add_history_flags(p) -> None:
    """``--db`` and ``--no-history``: where a command's record goes (``station history``)."""
    p.add_argument(
        "--db", type=Path, help="history database (default: $STATION_HISTORY_DB, else the user's data folder)"
    )
    p.add_argument("--no-history", action="store_true", help="append no record to the history")


def run(args) -> int:
    from station.formats.base import Output, check_writable, write_outputs
    from station.formats.samples import load_samples
    from station.formats.session_folder import load_robot_and_setup
    from station.formats.tables import check_same_robot, load_map, load_robot
    from station.jobs import verification

    for path, flag in ((args.report, "--report"), (args.plot, "--plot")):
        if path:
            check_writable(path, flag)
    session = args.samples if args.samples.is_dir() else None
    robot, setup, setup_where, session_samples = load_robot_and_setup(session, args.robot, args.setup)
    table = load_robot(args.table)
    residual_map = load_map(table, args.table)
    if robot is not None:
        where = str(args.robot) if args.robot else f"{session / 'session.toml'} [robot]"
        check_same_robot(table, str(args.table), robot, where)
    samples = load_samples(session_samples or args.samples)
    with parameters_as_flags(FLAGS):
        outcome = verification.verify_samples(
            samples,
            table,
            setup,
            table_where=str(args.table),
            setup_where=setup_where,
            robot=robot,
            residual_map=residual_map,
        )
    report = outcome.report
    outputs = []
    if args.report:
        outputs.append(Output.text(args.report, "--report", json.dumps(report.as_json(), indent=2) + "\n"))
    if args.plot:
        from station.view.plots import verification_figure

        data = outcome.row_errors()
        outputs.append(Output(args.plot, "--plot", lambda tmp: verification_figure(data, tmp)))
    write_outputs(outputs)
    print(verification.summary(report))
    if outputs:
        print("wrote " + ", ".join(str(o.path) for o in outputs))
    record_history(args, robot or table, "verify", samples.path, args.table, report.as_json())
    return EXIT_DRIFTED if report.verdict == "drifted" else 0


def record_history(args, robot, command: str, samples: str, table: Path, figures: dict) -> None:
    """Append the command's record to the history unless ``--no-history``; a history that cannot
    take it is said on stderr (the command's own result stands)."""
    if args.no_history:
        return
    import sys

    from station import history

    try:
        path = history.database_path(args.db)
        record = history.Record.of(robot, command, samples, table, figures)
        history.append(path, record)
    except InputError as exc:
        print(f"station: history not written: {exc}", file=sys.stderr)
