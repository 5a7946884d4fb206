"""Readers of the measurement programs ``station program`` writes, one per format, for a simulated
controller to run them and for the tests to check them: each returns the program's points in the
order it moves to them (:class:`ProgramPoint`: target id, gauge line, contact and stand-off joints
in the controller's convention [deg], the contact pose where the format carries it, the dwell), and
checks each target's moves (a joint move to the stand-off, a linear move onto the contact, the
dwell, a linear move back): ValueError naming what it met instead. A sweep program's passes
(:func:`read_sweep`, :class:`SweepPass`): each pass's moves checked (a joint move to its first
stand-off, a linear move onto the first waypoint, the dwell, blended linear moves through the
waypoints but the last, a linear move to it, the dwell, a linear move back to its last stand-off).
They read only what the station writes (no controller's full grammar); no real controller has
checked those programs.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_NUMBER = r"[-+0-9.eE]+"


@dataclass(frozen=True)
class ProgramPoint:
    """One measured target: ``target`` and ``line`` ids, ``contact_deg`` and ``standoff_deg`` (6,)
    as the controller reads its joints [deg], the contact ``pose`` in the format's own names (KRL
    ``X Y Z A B C``, RAPID ``x y z q1 q2 q3 q4``, Fanuc ``X Y Z W P R``, poses-csv its columns,
    URScript ``x_mm .. rz_deg``; mm and deg), ``dwell_s`` at the contact [s]."""

    target: int
    line: int
    contact_deg: np.ndarray
    standoff_deg: np.ndarray
    pose: dict[str, float]
    dwell_s: float


def read_program(path: Path, fmt: str) -> list[ProgramPoint]:
    """The points of the program file ``path`` in format ``fmt`` (``station program --format``
    names; krl: the ``.src``, its ``.dat`` read from beside it)."""
    path = Path(path)
    if fmt == "krl":
        return read_krl(path.read_text(), path.with_suffix(".dat").read_text())
    readers = {
        "urscript": read_urscript,
        "poses-csv": read_poses_csv,
        "rapid": read_rapid,
        "fanuc-ls": read_fanuc_ls,
    }
    return readers[fmt](path.read_text())


@dataclass(frozen=True)
class SweepPass:
    """One pass of a sweep program: its ``number`` and gauge ``line``, the waypoints' ``targets``
    and joints ``waypoints_deg`` (n, 6) in sweep order, its first and last stand-offs
    ``standoff_deg`` (2, 6), the controller's convention [deg], and the ``dwell_s`` at each end."""

    number: int
    line: int
    targets: np.ndarray
    waypoints_deg: np.ndarray
    standoff_deg: np.ndarray
    dwell_s: float


def read_sweep(path: Path, fmt: str) -> list[SweepPass]:
    """The passes of the sweep program ``path`` in format ``fmt`` ([] for a program of targets)."""
    path = Path(path)
    if fmt == "krl":
        return read_krl_sweep(path.read_text(), path.with_suffix(".dat").read_text())
    readers = {
        "urscript": read_urscript_sweep,
        "rapid": read_rapid_sweep,
        "fanuc-ls": read_fanuc_sweep,
        "poses-csv": read_poses_csv_sweep,
    }
    return readers[fmt](path.read_text()) if fmt in readers else []


def read_urscript_sweep(text: str) -> list[SweepPass]:
    """A URScript sweep's passes (joints written in rad; the waypoints' ids from the pass's comment)."""
    steps = _steps(
        text,
        r"# pass (\d+), line (\d+): (\d+) waypoints, targets (\d+)\.\.(\d+)",
        {
            "joint": r"movej\(\[([^\]]*)\]",
            "blend": r"movel\(\[([^\]]*)\].*, r=",
            "linear": r"movel\(\[([^\]]*)\]",
            "dwell": rf"sleep\(({_NUMBER})\)",
        },
    )
    passes = []
    for (number, line, count, first, last), found in steps:
        targets = np.arange(int(first), int(last) + 1)
        if len(targets) != int(count):
            raise ValueError(f"pass {number}: {count} waypoints, but targets {first}..{last}")
        points = _sweep_moves(number, found, len(targets))
        joints = np.degrees([_floats(q) for q in points])
        passes.append(SweepPass(number, line, targets, joints[1:-1], joints[[0, -1]], _dwell(found)))
    return passes


def read_poses_csv_sweep(text: str) -> list[SweepPass]:
    """A ``poses-csv`` sweep's passes (its ``pass`` column; [] without one): each pass's rows in
    order, its ends' stand-offs, the dwell at its first row (checked: no dwell between its ends)."""
    rows = list(csv.DictReader(io.StringIO(text)))
    if not rows or "pass" not in rows[0]:
        return []
    passes = []
    for number in dict.fromkeys(int(r["pass"]) for r in rows):
        on = [r for r in rows if int(r["pass"]) == number]
        if len({r["line"] for r in on}) != 1 or any(float(r["dwell_s"]) != 0 for r in on[1:-1]):
            raise ValueError(f"pass {number}: rows on more than one line, or a dwell between its ends")
        q = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in on])
        ends = np.array([[float(r[f"standoff_q{i}_deg"]) for i in range(1, 7)] for r in (on[0], on[-1])])
        targets = np.array([int(r["target"]) for r in on])
        passes.append(SweepPass(number, int(on[0]["line"]), targets, q, ends, float(on[0]["dwell_s"])))
    return passes


def read_krl_sweep(src: str, dat: str) -> list[SweepPass]:
    """A KRL sweep's passes: the moves from the ``.src``, the E6AXIS points from the ``.dat``."""
    steps = _steps(
        src,
        r"; pass (\d+), line (\d+):",
        {
            "joint": r"PTP (\w+)",
            "blend": r"LIN (\w+) C_DIS",
            "linear": r"LIN (\w+)$",
            "dwell": rf"WAIT SEC ({_NUMBER})",
        },
    )
    return _named_passes(steps, _krl_axes(dat), r"XT(\d+)_(ON|OFF)", str.upper)


def read_rapid_sweep(text: str) -> list[SweepPass]:
    """A RAPID sweep's passes: the moves of its ``! pass`` blocks, the jointtargets they name."""
    steps = _steps(
        text,
        r"! pass (\d+), line (\d+):",
        {
            "joint": r"MoveAbsJ (\w+),",
            "blend": r"MoveL CalcRobT\((\w+), \w+\), station_sweep, z",
            "linear": r"MoveL CalcRobT\((\w+),",
            "dwell": rf"WaitTime \\InPos, ({_NUMBER});",
        },
    )
    return _named_passes(steps, _rapid_joints(text), r"t(\d+)_(on|off)", str.lower)


def read_fanuc_sweep(text: str) -> list[SweepPass]:
    """A Fanuc ``.ls`` sweep's passes: the moves of ``/MN``, the positions of ``/POS`` (each named
    ``T<target> on`` or ``T<target> off``)."""
    main, positions = text.split("\n/MN\n", 1)[1].split("\n/POS\n", 1)
    steps = _steps(
        main,
        r"! pass (\d+) line (\d+) ;",
        {
            "joint": r"J P\[(\d+)\] \d+% FINE ;",
            "blend": r"L P\[(\d+)\] \d+mm/sec CNT100 ;",
            "linear": r"L P\[(\d+)\] \d+mm/sec FINE ;",
            "dwell": rf"WAIT ({_NUMBER})\(sec\) ;",
        },
    )
    found = re.findall(r"^P\[(\d+):\"T(\d+) (on|off)\"\]\{(.*?)\};", positions, re.M | re.S)
    joints = {n: _fanuc_joints(body) for n, _, _, body in found}
    names = {n: f"{target}_{kind}" for n, target, kind, _ in found}
    renamed = [
        (head, [(k, names.get(v, v) if k != "dwell" else v) for k, v in moves]) for head, moves in steps
    ]
    by_name = {names[n]: q for n, q in joints.items()}
    return _named_passes(renamed, by_name, r"(\d+)_(on|off)", str.lower)


def _named_passes(steps, joints: dict, pattern: str, case) -> list[SweepPass]:
    """Passes of a format naming its points: ``joints`` by name, ``pattern`` a name's target id and
    ``on``/``off`` (contact, stand-off); the names checked against the moves."""
    passes = []
    for (number, line, _), found in steps:
        names = [case(v) for v in _sweep_moves(number, found, None)]
        parsed = [re.fullmatch(pattern, n, re.I) for n in names]
        kinds = ["off", *["on"] * (len(names) - 2), "off"]
        if None in parsed or [m[2].lower() for m in parsed] != kinds:
            raise ValueError(
                f"pass {number}: moves to {names}: expected a stand-off, the waypoints, a stand-off"
            )
        targets = np.array([int(m[1]) for m in parsed])
        if targets[0] != targets[1] or targets[-1] != targets[-2]:
            raise ValueError(f"pass {number}: its stand-offs {names[0]}, {names[-1]} are not its ends'")
        missing = next((n for n in names if n not in joints), None)
        if missing is not None:
            raise ValueError(f"pass {number}: no point {missing}")
        q = np.array([joints[n] for n in names])
        passes.append(SweepPass(number, line, targets[1:-1], q[1:-1], q[[0, -1]], _dwell(found)))
    return passes


def _sweep_moves(number: int, found, count: int | None) -> list:
    """The points a pass's moves go to, in order: its first stand-off, the waypoints, its last
    stand-off (checked: ``count`` waypoints where given, the moves and dwells in the order a sweep
    makes them)."""
    kinds = [k for k, _ in found]
    n = count if count is not None else sum(k in ("blend", "linear") for k in kinds) - 1  # less the retreat
    expected = ["joint", "linear", "dwell", *["blend"] * (n - 2), "linear", "dwell", "linear"]
    if n < 2 or kinds != expected:
        raise ValueError(
            f"pass {number}: moves {kinds}, expected {expected if n >= 2 else 'two waypoints or more'}"
        )
    return [v for k, v in found if k != "dwell"]


def _krl_axes(dat: str) -> dict[str, np.ndarray]:
    """A KRL ``.dat``'s E6AXIS points by upper-case name: A1..A6 [deg]."""
    return {
        name.upper(): np.array([float(v) for v in re.findall(rf"\bA[1-6] ({_NUMBER})", body)])
        for name, body in re.findall(r"^DECL E6AXIS (\w+)=\{([^}]*)\}", dat, re.M)
    }


def _rapid_joints(text: str) -> dict[str, np.ndarray]:
    """A RAPID module's jointtargets by lower-case name: their robot axes [deg]."""
    return {
        name.lower(): _floats(values)
        for name, values in re.findall(r"CONST jointtarget (\w+) := \[\[([^\]]*)\]", text)
    }


def _fanuc_joints(body: str) -> np.ndarray:
    """A ``/POS`` entry's J1..J6 [deg]."""
    return np.array([float(v) for v in re.findall(rf"J[1-6]=\s*({_NUMBER}) deg", body)])


def left_out(text: str) -> list[int]:
    """The target ids a program's comments say it left out, in order (any format)."""
    return [int(t) for t in re.findall(r"(?:target|tgt) (\d+) left out", text)]


def read_urscript(text: str) -> list[ProgramPoint]:
    """A URScript program's points (joints written in rad)."""
    steps = _steps(
        text,
        r"# target (\d+), line (\d+): contact \[([^\]]*)\]",
        {
            "contact": r"q = station_target\(\d+, \[([^\]]*)\]\)",
            "standoff": r"q_off = station_standoff\(\[([^\]]*)\]",
            "joint off": r"movej\(q_off,",
            "linear on": r"movel\(q,",
            "dwell": rf"sleep\(({_NUMBER})\)",
            "linear off": r"movel\(q_off,",
        },
    )
    points = []
    for (target, line, pose), found in steps:
        _order(target, found, ["contact", "standoff", "joint off", "linear on", "dwell", "linear off"])
        names = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")
        contact, standoff = (np.degrees(_floats(found[i][1])) for i in (0, 1))
        points.append(ProgramPoint(target, line, contact, standoff, _named(names, pose), _dwell(found)))
    return points


def read_poses_csv(text: str) -> list[ProgramPoint]:
    """A ``poses-csv`` file's rows (every column beside the ids and joints is the pose)."""
    points = []
    for row in csv.DictReader(io.StringIO(text)):
        if "pass" in row:  # a sweep's waypoints: read_poses_csv_sweep
            return []
        contact = np.array([float(row[f"q{i}_deg"]) for i in range(1, 7)])
        standoff = np.array([float(row[f"standoff_q{i}_deg"]) for i in range(1, 7)])
        joints = {f"q{i}_deg" for i in range(1, 7)} | {f"standoff_q{i}_deg" for i in range(1, 7)}
        pose = {k: float(v) for k, v in row.items() if k not in joints | {"target", "line", "dwell_s"}}
        points.append(
            ProgramPoint(int(row["target"]), int(row["line"]), contact, standoff, pose, float(row["dwell_s"]))
        )
    return points


def read_krl(src: str, dat: str) -> list[ProgramPoint]:
    """A KRL program's points: the moves from the ``.src``, the E6AXIS points and the contact
    poses (``X Y Z A B C``) from the ``.dat``."""
    axes = _krl_axes(dat)
    poses = {
        int(t): dict(re.findall(rf"\b([XYZABC]) ({_NUMBER})", body))
        for t, body in re.findall(r"^; target (\d+), line \d+: contact pose \{([^}]*)\}", dat, re.M)
    }
    steps = _steps(
        src,
        r"; target (\d+), line (\d+):",
        {"joint": r"PTP (\w+)", "linear": r"LIN (\w+)", "dwell": rf"WAIT SEC ({_NUMBER})"},
    )
    points = []
    for (target, line, _), found in steps:
        off, on = _moves(target, found, f"XT{target}_OFF", f"XT{target}_ON", str.upper)
        pose = {k: float(v) for k, v in poses[target].items()}
        points.append(ProgramPoint(target, line, axes[on], axes[off], pose, _dwell(found)))
    return points


def read_rapid(text: str) -> list[ProgramPoint]:
    """A RAPID module's points: the jointtargets each ``station_target`` call names, the contact
    pose from the comment before it (``x y z`` mm, ``q1..q4`` = w, x, y, z)."""
    joints = _rapid_joints(text)
    proc = re.search(
        r"PROC station_target\(jointtarget standoff, jointtarget contact\)(.*?)ENDPROC", text, re.S
    )
    if proc is None:
        raise ValueError("no PROC station_target(jointtarget standoff, jointtarget contact)")
    moves = [m.strip() for m in proc[1].splitlines() if re.match(r"\s*(Move|Wait)", m)]
    if len(moves) != len(_RAPID_MOVES) or not all(map(str.startswith, moves, _RAPID_MOVES)):
        raise ValueError(f"station_target moves {moves}, expected {_RAPID_MOVES}")
    dwell = float(moves[2].removeprefix(_RAPID_MOVES[2]).rstrip(";"))
    steps = _steps(
        text,
        r"! target (\d+), line (\d+): contact \[\[([^\]]*)\], \[([^\]]*)\]\]",
        {"call": r"station_target (\w+), (\w+);"},
    )
    points = []
    for (target, line, position, quaternion), found in steps:
        _order(target, found, ["call"])
        off, on = (name.lower() for name in found[0][1])
        pose = _named(("x", "y", "z", "q1", "q2", "q3", "q4"), f"{position}, {quaternion}")
        points.append(ProgramPoint(target, line, joints[on], joints[off], pose, dwell))
    return points


_RAPID_MOVES = [
    "MoveAbsJ standoff,",
    "MoveL CalcRobT(contact,",
    "WaitTime \\InPos,",
    "MoveL CalcRobT(standoff,",
]
"""How each RAPID ``station_target`` line begins, in order."""


def read_fanuc_ls(text: str) -> list[ProgramPoint]:
    """A Fanuc ``.ls`` program's points: the moves of ``/MN``, the joint positions of ``/POS``, the
    contact pose from the comments (``X Y Z`` mm, ``W P R`` deg)."""
    main, positions = text.split("\n/MN\n", 1)[1].split("\n/POS\n", 1)
    joints = {
        int(n): _fanuc_joints(body)
        for n, body in re.findall(r"^P\[(\d+)(?::\"[^\"]*\")?\]\{(.*?)\};", positions, re.M | re.S)
    }
    steps = _steps(
        main,
        r"! tgt (\d+) line (\d+) ;",
        {
            "position": rf"! X ({_NUMBER}) Y ({_NUMBER}) Z ({_NUMBER}) ;",
            "orientation": rf"! W ({_NUMBER}) P ({_NUMBER}) R ({_NUMBER}) ;",
            "joint": r"J P\[(\d+)\] \d+% FINE ;",
            "linear": r"L P\[(\d+)\] \d+mm/sec FINE ;",
            "dwell": rf"WAIT ({_NUMBER})\(sec\) ;",
        },
    )
    points = []
    for (target, line, _), found in steps:
        _order(target, found[:2], ["position", "orientation"])
        pose = dict(zip("XYZWPR", (float(x) for _, group in found[:2] for x in group), strict=True))
        off, on = _moves(target, found[2:], None, None, int)
        points.append(ProgramPoint(target, line, joints[on], joints[off], pose, _dwell(found)))
    return points


def _steps(text: str, start: str, kinds: dict[str, str]) -> list[tuple[tuple, list[tuple[str, object]]]]:
    """The text's targets: each line matching ``start`` (target id, line id, the rest of its
    groups) and, until the next, the lines matching a pattern of ``kinds`` as ``(kind, groups)``
    (one group: a string)."""
    steps: list = []
    for raw in text.splitlines():
        line = raw.strip()
        head = re.search(start, line)
        if head is not None:
            target, gauge, *rest = head.groups()
            steps.append(((int(target), int(gauge), *rest) if rest else (int(target), int(gauge), None), []))
            continue
        for kind, pattern in kinds.items():
            found = re.match(pattern, re.sub(r"^\d+:\s*", "", line))
            if found is not None and steps:
                groups = found.groups()
                steps[-1][1].append((kind, groups[0] if len(groups) == 1 else groups))
                break
    return steps


def _order(target: int, found, kinds: list[str]) -> None:
    """ValueError unless ``found``'s kinds are ``kinds``."""
    if [k for k, _ in found] != kinds:
        raise ValueError(f"target {target}: moves {[k for k, _ in found]}, expected {kinds}")


def _moves(target: int, found, off, on, key):
    """The stand-off and contact points of a target's joint move, linear on, dwell, linear off
    (checked: the joint move and the retreat name the stand-off ``off``, the approach ``on``;
    None: any, the same stand-off both times)."""
    _order(target, found, ["joint", "linear", "dwell", "linear"])
    names = [key(found[i][1]) for i in (0, 1, 3)]
    if names[0] != names[2] or (off is not None and names[:2] != [off, on]):
        raise ValueError(f"target {target}: moves to {names}, expected {[off, on, off]}")
    return names[0], names[1]


def _dwell(found) -> float:
    return float(next(v for k, v in found if k == "dwell"))


def _floats(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split(",")])


def _named(names, text: str) -> dict[str, float]:
    values = _floats(text)
    if len(values) != len(names) or not all(math.isfinite(v) for v in values):
        raise ValueError(f"a pose of {len(names)} numbers expected, got {text!r}")
    return dict(zip(names, values.tolist(), strict=True))
