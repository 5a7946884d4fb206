"""``station program PLAN.csv --robot R --format urscript|poses-csv|krl|rapid|fanuc-ls --out F``: the
measurement program that brings the tool onto each planned contact (the geometry:
``station.jobs.measurement``; the writers and their table of formats: ``station.jobs.programs``)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from errors import InputError
from station.commands.flags import number
from station.jobs.programs import FORMATS

_positive = number(float, "a number", lambda v: 0 < v < 1e4, "{:g} must be above 0 and below 10000")


def register(sub) -> None:
    p = sub.add_parser(
        "program",
        help="write the measurement program for a plan (URScript, KRL, RAPID, Fanuc LS or a pose list)",
    )
    p.add_argument("plan", type=Path, help="plan CSV (station plan): targets, joints, contact poses")
    p.add_argument("--robot", type=Path, required=True, help="nominal robot TOML the plan was made for")
    p.add_argument(
        "--format",
        choices=tuple(FORMATS),
        required=True,
        help="; ".join(f"{name}: {f.help} ({f.extension})" for name, f in FORMATS.items())
        + "; joints in the controller's convention (the robot file's [controller])",
    )
    p.add_argument("--out", type=Path, required=True, help="program file to write (krl: the .src)")
    p.add_argument(
        "--standoff-mm",
        type=_positive,
        default=20.0,
        metavar="MM",
        help="stand-off back along the approach (20)",
    )
    p.add_argument(
        "--dwell-s",
        type=_positive,
        default=3.0,
        metavar="S",
        help="dwell at each contact, s (3: settle + capture)",
    )
    p.add_argument(
        "--sweep",
        action="store_true",
        help="the plan is a sweep plan (station plan --sweep): each pass swept through its waypoints "
        "(blended); refused for a plan without a pass column (a sweep plan is written so without it too)",
    )
    p.add_argument(
        "--table",
        type=Path,
        help="the offline second pass: a corrected table (station calibrate --out) whose model brings the "
        "tool onto each planned contact pose: the contact joints are corrected, the stand-offs follow",
    )
    p.add_argument(
        "--session",
        type=Path,
        metavar="DIR",
        help="with --table: the first pass's session folder; the targets it has not measured go first",
    )
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from station.formats.base import Output, check_writable, write_outputs
    from station.formats.plan import load_plan
    from station.formats.tables import load_robot
    from station.jobs import measurement, programs
    from station.jobs.programs.common import Program

    for path in programs.paths(args.format, args.out):
        check_writable(path, "--out")
    plan, robot = load_plan(args.plan), load_robot(args.robot)
    if args.sweep and not plan.is_sweep:
        raise InputError(
            f"--sweep: {args.plan} has no pass column, a static plan: make a sweep plan with "
            "`station plan --sweep` (or leave out --sweep for a stop-at-each-target program)"
        )
    if args.session is not None and args.table is None:
        raise InputError("--session goes with --table: the second pass orders the corrected targets by it")
    if args.table is not None:
        plan, robot = _second_pass(args, plan, robot)
    motion = measurement.Motion(standoff_mm=args.standoff_mm, dwell_s=args.dwell_s)
    found = measurement.measurement(plan, robot, str(args.plan), motion)
    files = programs.write(args.format, Program(found, robot, str(args.plan), motion, args.out))
    write_outputs([Output.text(path, "--out", text) for path, text in files])
    source = "the plan" if plan.pose is not None else "the nominal TCP at the plan's joints (an older plan)"
    if found.skipped.any():
        left = ", ".join(str(int(t)) for t in plan.target[found.skipped])
        print(f"left out (no stand-off of even 2 mm within the joint limits): targets {left}")
    short = int((found.distance_mm < args.standoff_mm).sum())
    if short:
        least = np.nanmin(found.distance_mm)
        print(f"{short} targets near a joint limit get a shorter stand-off (down to {least:g} mm)")
    print(f"{len(plan)} targets, contact poses from {source}; wrote {', '.join(str(p) for p, _ in files)}")
    return 0


def _second_pass(args, plan, nominal):
    """The plan with its contact joints corrected by ``--table`` (the targets ``--session`` did not
    measure first) and the table to write the program with; says what it did."""
    import numpy as np

    from station.formats.session_folder import measured_targets
    from station.formats.tables import check_same_robot, check_same_tool, load_map, load_robot
    from station.jobs.correction import offline_correction, unmeasured_first

    table = load_robot(args.table)
    check_same_robot(table, str(args.table), nominal, str(args.robot))
    check_same_tool(table, str(args.table), nominal, str(args.robot))
    setup = samples = None
    if args.session is not None:
        from station.formats.samples import load_samples
        from station.formats.session_folder import load_session

        _, setup, where = load_session(args.session)
        samples = load_samples(where)
    else:
        print(
            "warning: without --session the table's frame is taken for the setup's (a calibration holds the "
            "robot's base, which the lines' placement absorbs): give the first pass's session folder, whose "
            "lines register it, or the contacts may land millimetres off"
        )
    fix = offline_correction(plan, nominal, table, setup, samples, load_map(table, args.table))
    plan = replace(plan, q_deg=fix.q_deg)
    moved = fix.shift_mm[fix.ok]
    print(
        f"second pass: {int(fix.ok.sum())} of {len(plan)} contact joints corrected by {args.table} "
        f"(the contacts move {np.sqrt(np.mean(moved**2)) if moved.size else 0.0:.3f} mm RMS, "
        f"max {moved.max(initial=0.0):.3f}); the stand-offs follow"
    )
    if not fix.ok.all():
        kept = ", ".join(str(int(t)) for t in plan.target[~fix.ok])
        print(f"kept their planned joints (a joint limit, the wrist or a large move): targets {kept}")
    if args.session is not None:
        measured = measured_targets(args.session)
        unknown = measured - {int(t) for t in plan.target}
        if unknown:
            raise InputError(
                f"{args.session}: measured target {min(unknown)}, which {args.plan} does not have: "
                "another plan's session"
            )
        plan, first = unmeasured_first(plan, measured)
        print(f"{first} targets not measured in {args.session} first, then the {len(plan) - first} measured")
    return plan, table
