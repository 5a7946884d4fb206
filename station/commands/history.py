"""``station history [ROBOT]``: the robots in the calibration history, or one robot's records with
every parameter that moved between consecutive calibrations."""

from __future__ import annotations

import functools
import json
import unicodedata
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
        known = ", ".join(escaped(r["robot"]) for r in history.robots(path)) or "none"
        raise InputError(f"{path}: no records of robot {args.robot!r} (robots: {known})")
    moved = history.moves(found)
    if args.plot:
        from station.formats.base import Output, check_writable, write_outputs
        from station.view.plots import history_figure

        check_writable(args.plot, "--plot")
        shown = [m | {"param": escaped(m["param"])} for m in moved]
        figure = functools.partial(history_figure, escaped(args.robot), found, shown)
        write_outputs([Output(args.plot, "--plot", figure)])
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
    lines = [
        f"{'robot':24}{'name':16}{'records':>8}{'calibr.':>8}  {'last record':27}state of its current table"
    ]
    for r in found:
        lines.append(
            f"{escaped(r['robot']):24}{escaped(r['name']):16}{r['records']:>8}{r['calibrations']:>8}  "
            f"{escaped(r['last_utc']):27}{escaped(r['state'] or '-')}"
        )
    return "\n".join(lines)


def records_text(robot: str, found: list[dict], moved: list[dict]) -> str:
    """One line per record, then every flagged move (``J2.a_mm +0.41 mm, 6.2 sigma since ...``)."""
    from calib.params import display_unit

    lines = [f"robot {escaped(robot)}: {len(found)} records; {state_text(found)}"]
    for r in found:
        r = {k: v if k in ("id", "rmse_mm", "figures", "current") else escaped(v or "") for k, v in r.items()}
        rmse = "" if r["rmse_mm"] is None else f"{r['rmse_mm']:.3f} mm"
        aside = "" if r["current"] else "; not its current table: leaves its state"
        lines.append(
            f"  #{r['id']:<4} {r['time_utc']}  {r['command']:9} {r['verdict']:12} {rmse:>10}  "
            f"{r['samples']} (table {r['table']}, {r['table_hash'][:12]}: {r['judged']}{aside})"
        )
    if not moved:
        lines.append("no parameter moved between consecutive calibrations (beyond 3 combined sigmas)")
    for m in moved:
        unit = display_unit(m["param"])[1]
        lines.append(
            f"moved: {escaped(m['param'])} {m['change']:+.3g} {unit}, {m['sigmas']:.1f} sigma since "
            f"{m['since']} (record #{m['record']}): a collision or wear?"
        )
    return "\n".join(lines)


def state_text(found: list[dict]) -> str:
    """``state: holds (the table of calibration #1 (...))``: the latest verdict on the robot's
    current table (``station.history.judged``)."""
    on_current = [r for r in found if r["current"]]
    if not on_current:
        return "state: none (no calibration or verification of a corrected table)"
    last = on_current[-1]
    return f"state: {escaped(last['verdict'] or '-')} (its current table: {escaped(last['judged'])})"


HIDDEN = {"Cc", "Cf", "Cs", "Zl", "Zp"}
"""Unicode categories a terminal does not show as themselves: controls (newline, ESC), format
characters (a right-to-left override), lone surrogates, line and paragraph separators."""


def escaped(text: str) -> str:
    """``text`` as one line of what it holds: a character of ``HIDDEN`` as its Python escape
    (``\\n``, ``\\x1b``, ``\\u202e``), so that a stored name forges no line and colours no terminal."""
    if text.isprintable():
        return text
    return "".join(
        c.encode("unicode_escape", "backslashreplace").decode("ascii")
        if unicodedata.category(c) in HIDDEN
        else c
        for c in text
    )
