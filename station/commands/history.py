"""``station history [ROBOT]``: the robots in the calibration history, or one robot's records with
every parameter that moved between consecutive calibrations."""

from __future__ import annotations

import json
from pathlib import Path

from errors import InputError


def register(sub) -> None:
    p = sub.add_parser("history", help="the calibration history: the robots, or one robot's records")
    p.add_argument("robot", nargs="?", help="a robot's serial (or name, without one): list its records")
    p.add_argument(
        "--db", type=Path, help="history database (default: $STATION_HISTORY_DB, else the user's data folder)"
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--plot", type=Path, help="PNG to write (with ROBOT): accuracy and verdicts over time")
    p.set_defaults(func=run)


def run(args) -> int:
    from station import history

    path = history.database_path(args.db)
    if args.robot is None:
        if args.plot:
            raise InputError("--plot: name a robot (station history ROBOT --plot P.png)")
        found = history.robots(path)
        print(json.dumps(found, indent=2) if args.json else robots_text(found, path))
        return 0
    found = history.records(path, args.robot)
    if not found:
        known = ", ".join(r["robot"] for r in history.robots(path)) or "none"
        raise InputError(f"{path}: no records of robot {args.robot!r} (robots: {known})")
    moved = history.moves(found)
    if args.plot:
        from station.formats.base import Output, check_writable, write_outputs
        from station.view.plots import history_figure

        check_writable(args.plot, "--plot")
        write_outputs(
            [Output(args.plot, "--plot", lambda tmp: history_figure(args.robot, found, moved, tmp))]
        )
    if args.json:
        print(json.dumps({"robot": args.robot, "records": found, "moved": moved}, indent=2))
    else:
        print(records_text(args.robot, found, moved))
    if args.plot:
        print(f"wrote {args.plot}")
    return 0


def robots_text(found: list[dict], path: Path) -> str:
    if not found:
        return f"{path}: no records yet"
    lines = [f"{'robot':24}{'name':16}{'records':>8}{'calibr.':>8}  last"]
    for r in found:
        lines.append(
            f"{r['robot']:24}{r['name']:16}{r['records']:>8}{r['calibrations']:>8}  "
            f"{r['last_utc']} {r['last_verdict'] or ''}"
        )
    return "\n".join(lines)


def records_text(robot: str, found: list[dict], moved: list[dict]) -> str:
    """One line per record, then every flagged move (``J2.a_mm +0.41 mm, 6.2 sigma since ...``)."""
    from calib.params import display_unit

    lines = [f"robot {robot}: {len(found)} records"]
    for r in found:
        rmse = "" if r["rmse_mm"] is None else f"{r['rmse_mm']:.3f} mm"
        lines.append(
            f"  #{r['id']:<4} {r['time_utc']}  {r['command']:9} {r['verdict'] or '':12} {rmse:>10}  "
            f"{r['samples']} (table {r['table']}, {r['table_hash'][:12]})"
        )
    if not moved:
        lines.append("no parameter moved between consecutive calibrations (beyond 3 combined sigmas)")
    for m in moved:
        unit = display_unit(m["param"])[1]
        lines.append(
            f"moved: {m['param']} {m['change']:+.3g} {unit}, {m['sigmas']:.1f} sigma since "
            f"{m['since']} (record #{m['record']}): a collision or wear?"
        )
    return "\n".join(lines)
