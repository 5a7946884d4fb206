"""``station export``: the robot model where robots use it (URDF, UR's kinematics YAML, D-H CSV)."""

from __future__ import annotations

import sys
from pathlib import Path

from errors import InputError


def register(sub) -> None:
    p = sub.add_parser(
        "export", help="write a (corrected) robot table as URDF, UR kinematics YAML or D-H CSV"
    )
    p.add_argument("table", type=Path, help="robot model TOML, e.g. the corrected table of station calibrate")
    p.add_argument(
        "--format",
        required=True,
        dest="fmt",
        metavar="FORMAT",
        help="urdf: a URDF chain base_link -> tcp; ur-yaml: Universal Robots' kinematics file; "
        "dh-csv: D-H rows (with --robot, the deltas)",
    )
    p.add_argument("--out", type=Path, required=True, help="file to write")
    p.add_argument(
        "--robot", type=Path, help="nominal robot TOML: the deltas of dh-csv, a controller hash for ur-yaml"
    )
    p.add_argument(
        "--hash", dest="hash_", metavar="HASH", help="ur-yaml: the controller's calibration hash (calib_...)"
    )
    p.set_defaults(func=run)


def run(args) -> int:
    from station.formats.base import Output, check_writable, write_outputs
    from station.formats.tables import check_same_robot, load_robot
    from station.jobs import export as exporting

    if args.fmt not in exporting.FORMATS:
        raise InputError(f"--format {args.fmt!r}: must be one of {', '.join(exporting.FORMATS)}")
    check_writable(args.out, "--out")
    if args.hash_ is not None and args.fmt != "ur-yaml":
        raise InputError(f"--hash: only --format ur-yaml carries a controller hash, not {args.fmt}")
    robot = load_robot(args.table)
    nominal = None
    if args.robot is not None:
        nominal = load_robot(args.robot)
        check_same_robot(robot, str(args.table), nominal, str(args.robot))
    result = exporting.export(robot, args.fmt, source=str(args.table), nominal=nominal, hash_=args.hash_)
    write_outputs([Output.text(args.out, "--out", result.text)])
    left_out = exporting.map_left_out(robot, args.fmt, str(args.table))
    if left_out is not None:
        print(f"station: {left_out}", file=sys.stderr)
    for note in result.notes:
        print(f"note: {note}")
    for warning in result.warnings:
        print(f"warning: {warning}")
    print(f"wrote {args.out} ({args.fmt})")
    return 0
