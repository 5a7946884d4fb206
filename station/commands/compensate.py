"""``station compensate``: rewrite a joint program so the calibrated robot reaches what it meant."""

from __future__ import annotations

import json
from pathlib import Path

from station.commands.flags import number

_angle = number(float, "a number", lambda v: 0.0 <= v < 90.0, "{:g} must lie in [0, 90) deg")


def register(sub) -> None:
    p = sub.add_parser(
        "compensate", help="rewrite a program's joints so the calibrated robot reaches the nominal poses"
    )
    p.add_argument("program", type=Path, help="program CSV: q1_deg..q6_deg per row, other columns kept")
    p.add_argument(
        "--table", type=Path, required=True, help="calibrated robot TOML (station calibrate --out)"
    )
    p.add_argument(
        "--robot", type=Path, required=True, help="nominal robot TOML the program was written with"
    )
    p.add_argument("--out", type=Path, required=True, help="compensated program CSV to write")
    p.add_argument("--report", type=Path, help="report JSON to write")
    p.add_argument(
        "--wrist-margin-deg",
        type=_angle,
        default=10.0,
        metavar="DEG",
        help="rows whose axes 4 and 6 are closer than this keep their joints (default 10)",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from calib.compensation import CompensationOptions
    from station.formats.base import Output, check_writable, write_outputs
    from station.formats.program import load_program
    from station.formats.tables import check_same_robot, check_same_tool, load_map, load_robot
    from station.jobs import compensate as compensation

    check_writable(args.out, "--out")
    if args.report:
        check_writable(args.report, "--report")
    program = load_program(args.program)
    table, nominal = load_robot(args.table), load_robot(args.robot)
    check_same_robot(table, str(args.table), nominal, str(args.robot))
    check_same_tool(table, str(args.table), nominal, str(args.robot))
    table.covariance(str(args.table))  # a malformed covariance is bad input before any work
    residual_map = load_map(table, args.table)
    outcome = compensation.run(
        program,
        table,
        nominal,
        table_where=str(args.table),
        nominal_where=str(args.robot),
        options=CompensationOptions(wrist_margin=np.radians(args.wrist_margin_deg)),
        residual_map=residual_map,
    )
    outputs = [Output.text(args.out, "--out", outcome.text)]
    if args.report:
        outputs.append(Output.text(args.report, "--report", json.dumps(outcome.report, indent=2) + "\n"))
    write_outputs(outputs)
    print(compensation.summary(outcome.report))
    print(f"wrote {args.out}" + (f" and {args.report}" if args.report else ""))
    return 0
