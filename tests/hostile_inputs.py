"""Hostile inputs: every file the station reads, mutated, through the command that reads it.

A :class:`Kit` holds one valid file of each kind (robot and setup TOML, samples and hold-out CSV, a
plan, a station config whose devices are not there, a session folder, an IPA series). A case
mutates one of them (:func:`mutate`: a TOML value or a CSV cell set to NaN, infinity, 1e308, text,
the wrong type or shape; a key, column or rows removed; the bytes truncated or garbled), runs the
command that reads it in-process (``station.cli.main``) and checks the contract (:func:`run_case`):
exit 0 or 2 (1 only where a valid input reaches the devices, which are absent: one
``device error`` line), one line on stderr with warnings counted as lines, no traceback, and on
exit 2 nothing written to the output (for ``--resume``: the session folder unchanged).

The choices come from Hypothesis (``draw`` is ``data.draw`` of ``hypothesis.strategies.data()``),
so a run is reproducible from its seed and a failing case shrinks to a small one. Used by
``tests/system/test_fuzz_inputs.py`` and ``benchmarks/fuzz_inputs.py``.
"""

from __future__ import annotations

import contextlib
import csv
import io
import shutil
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomli_w
import tomllib
from hypothesis import strategies as st

import configs
from sim_fixtures.scenario import write_scenario
from station import cli
from station.acquire import runner
from station.formats.plan import Plan

ABSENT_HOST = "127.0.0.253"  # nothing listens here: simulated servers in tests take .2 to .250

# Values a mutation writes: hostile ones, and valid ones at the edges of the ranges the loaders
# accept (lengths 1e5 mm, joints 3600 deg, table angles 360 deg, sigmas 1e-6 .. 100 mm), where the
# maths must still hold.
TOML_VALUES = (
    float("nan"), float("inf"), float("-inf"), 1e308, -1e308, 1e-308, 0.0, -1.0, 0, -1, 2**63 - 1, 10**30,
    "", "x", "\x00", True, [], {}, [0.0, 0.0, 0.0], [1.0, 2.0], [1.0] * 7, "nan",
    1e5, -1e5, 3600.0, -3600.0, 360.0, 1e-6, 100.0, [1e5, -1e5, 1e5], [1e-6, 0.0, 0.0],
)  # fmt: skip
CSV_CELLS = (
    "nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e400", "1e-320", "", " ", "abc", "0", "-0", "1.5",
    "-1", "99999999999999999999", "1,5", "0x1A", '"', "\x00", "\ufeff1", "9" * 400, "2147483648",
    "1e5", "-100000", "3600", "-3600", "1e-6",
)  # fmt: skip
GARBAGE = (b"\xff\xfe\x00", b"\x00" * 8, b"[[[[", b'"""', b"\n\n,,,\n", "é".encode("latin-1"))

Draw = Callable[[st.SearchStrategy], object]


@dataclass(frozen=True)
class Kit:
    """One valid file of every kind the station reads (see the module notes)."""

    folder: Path
    robot: Path
    setup: Path
    samples: Path
    holdout: Path
    plan: Path
    config: Path
    session: Path
    ipa: Path
    placements: Path
    corrected: Path
    program: Path


def make_kit(folder: Path) -> Kit:
    """Write the valid files: a simulated 3-line cell (15 samples a line, 4 held out; link masses and
    a payload in its robot and setup files), a plan of
    its configurations, a station config with absent devices and one retry, a session folder with
    40 of the plan's 45 targets measured, an IPA series of 5 rows, and the simulated cell's setup
    with its gauge-line placements (for ``station plan``), the corrected table of the samples and a
    program of 8 rows (for ``station compensate``)."""
    folder = Path(folder)
    sc = write_scenario(folder, seed=1, n_lines=3, n_per_line=15, n_holdout_per_line=4)
    _add_masses(sc.robot, sc.setup)
    plan = folder / "plan.csv"
    plan.write_text(Plan.of(sc.train.q_deg, sc.train.line).csv_text())
    config = folder / "station.toml"
    config.write_text(tomli_w.dumps(absent_devices()))
    session = folder / "session"
    inputs = runner.new_session(session, config, plan)
    inputs.folder.make()  # a session run makes it once the devices answer
    for k in range(40):
        inputs.folder.append(*_session_row(sc.train, k))
    ipa = folder / "series.csv"
    ipa.write_text(_ipa_series(sc.train.q_deg[:5]))
    placements = folder / "placements.toml"
    shutil.copy(configs.path("setups/sim.toml"), placements)
    corrected = folder / "corrected.toml"
    with contextlib.redirect_stdout(io.StringIO()):
        cli.main(["calibrate", str(sc.samples), "--robot", str(sc.robot), "--setup", str(sc.setup),
                  "--out", str(corrected)])  # fmt: skip
    program = folder / "program.csv"
    program.write_text(_program(sc.train.q_deg[:8]))
    return Kit(
        folder, sc.robot, sc.setup, sc.samples, sc.holdout, plan, config, session, ipa, placements,
        corrected, program,
    )  # fmt: skip


def _add_masses(robot: Path, setup: Path) -> None:
    """Link masses in the robot file and a payload in the setup (the optional keys of the gravity
    torques, so that they are mutated too)."""
    data = tomllib.loads(robot.read_text())
    for k, joint in enumerate(data["joints"]):
        joint.update(mass_kg=30.0 - 4.0 * k, com_mm=[-50.0, 0.0, 10.0 * k])
    robot.write_text(tomli_w.dumps(data))
    data = tomllib.loads(setup.read_text())
    data["payload"] = {"mass_kg": 2.5, "com_mm": [0.0, 0.0, 60.0]}
    setup.write_text(tomli_w.dumps(data))


def absent_devices() -> dict:
    """A station config whose devices are not there: connection refused at once, one attempt."""
    return {
        "robot": {"kind": "rtde", "host": ABSENT_HOST},
        "drawstring": {"kind": "modbus_tcp", "host": ABSENT_HOST, "port": 5020},
        "dial": {"port": "/nonexistent/station-dial"},
        "reconnect": {"attempts": 1},
    }


def _session_row(train, k: int) -> tuple[dict, list[dict]]:
    q = {f"q{i + 1}_deg": float(v) for i, v in enumerate(train.q_deg[k])}
    row = {"sample": k, "target": k, "line": int(train.line[k]), **q, "length_mm": float(train.length_mm[k])}
    row.update(dial_mm=float(train.dial_mm[k]), t_s=1.5 * k, window_s=0.01, t_wall_s=1.7e9 + 1.5 * k)
    raw = [{"sample": k, "k": j, **q, "length_mm": row["length_mm"]} for j in range(2)]
    return row, raw


def _program(q_deg: np.ndarray) -> str:
    rows = ["step,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,speed"]
    rows += [",".join([f"p{k}", *(f"{v:.6f}" for v in q), "0.25"]) for k, q in enumerate(q_deg)]
    return "\n".join(rows) + "\n"


def _ipa_series(q_deg: np.ndarray) -> str:
    header = ["Timestamp", "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint"]
    header += ["wrist_2_joint", "wrist_3_joint", "measurement_x", "measurement_y", "measurement_z"]
    rows = [";".join(header)]
    for k, q in enumerate(np.radians(q_deg)):
        values = [2.0e13 + k, *q, 1500.0 + k, -900.0, -450.0]
        rows.append(";".join(f"{v:.6g}".replace(".", ",") for v in values))
    return "\n".join(rows) + "\n"


# -- what each input feeds --------------------------------------------------------------------------
@dataclass(frozen=True)
class Target:
    """An input: the file mutated (``kit`` attribute, or a file of the session folder), its format
    (``toml``, ``csv`` or ``ipa``: ``;``-separated), the command line reading it from ``case`` (a
    fresh folder: the mutated file at ``case / name``, outputs beside it), the outputs that must not
    appear on exit 2, and whether a valid input reaches the (absent) devices."""

    name: str
    source: str
    fmt: str
    argv: Callable[[Kit, Path, Path], list]
    outputs: tuple[str, ...] = ()
    reaches_devices: bool = False
    session_file: str | None = None


def _calibrate(kit: Kit, case: Path, files: dict) -> list:
    inputs = {"samples": kit.samples, "robot": kit.robot, "setup": kit.setup, "holdout": kit.holdout, **files}
    return [
        "calibrate", inputs["samples"], "--robot", inputs["robot"], "--setup", inputs["setup"],
        "--holdout", inputs["holdout"], "--out", case / "corrected.toml", "--report", case / "report.json",
    ]  # fmt: skip


def _compensate_inputs(kit: Kit, source: str, mutated: Path) -> list:
    files = {"program": kit.program, "corrected": kit.corrected, "robot": kit.robot, source: mutated}
    return [files["program"], "--table", files["corrected"], "--robot", files["robot"]]


CALIBRATE_OUT = ("corrected.toml", "report.json")
TARGETS = (
    Target("robot", "robot", "toml", lambda k, c, f: _calibrate(k, c, {"robot": f}), CALIBRATE_OUT),
    Target("setup", "setup", "toml", lambda k, c, f: _calibrate(k, c, {"setup": f}), CALIBRATE_OUT),
    Target("samples", "samples", "csv", lambda k, c, f: _calibrate(k, c, {"samples": f}), CALIBRATE_OUT),
    Target("holdout", "holdout", "csv", lambda k, c, f: _calibrate(k, c, {"holdout": f}), CALIBRATE_OUT),
    Target(
        "plan", "plan", "csv",
        lambda k, c, f: ["sample", "--config", k.config, "--plan", f, "--out", c / "sess"],
        ("sess",), reaches_devices=True,
    ),
    Target("station config", "config", "toml", lambda k, c, f: ["read", "--config", f], reaches_devices=True),
    Target(
        "session.toml (calibrate)", "session", "toml",
        lambda k, c, f: ["calibrate", f.parent, "--out", c / "corrected.toml"], ("corrected.toml",),
        session_file="session.toml",
    ),
    Target(
        "session samples.csv (calibrate)", "session", "csv",
        lambda k, c, f: ["calibrate", f.parent, "--out", c / "corrected.toml"], ("corrected.toml",),
        session_file="samples.csv",
    ),
    *(
        Target(
            f"session {name} (resume)", "session", fmt, lambda k, c, f: ["sample", "--resume", f.parent],
            reaches_devices=True, session_file=name,
        )
        for name, fmt in (("session.toml", "toml"), ("samples.csv", "csv"), ("raw.csv", "csv"))
    ),
    Target(
        "setup placements (plan)", "placements", "toml",
        lambda k, c, f: ["plan", "--robot", k.robot, "--setup", f, "--out", c / "plan.csv",
                         "--per-line", "20", "--no-suggest", "--report", c / "plan.json"],
        ("plan.csv", "plan.json"),
    ),
    *(
        Target(
            name, source, fmt,
            lambda k, c, f, src=source: ["compensate", *_compensate_inputs(k, src, f), "--out", c / "out.csv",
                                         "--report", c / "out.json"],
            ("out.csv", "out.json"),
        )
        for name, source, fmt in (
            ("program (compensate)", "program", "csv"),
            ("corrected table (compensate)", "corrected", "toml"),
            ("nominal robot (compensate)", "robot", "toml"),
        )
    ),
    Target(
        "IPA series", "ipa", "ipa", lambda k, c, f: ["import-ipa", f, "--out", c / "out.csv"], ("out.csv",)
    ),
)  # fmt: skip


# -- mutations --------------------------------------------------------------------------------------
def mutate(draw: Draw, text: str, fmt: str) -> tuple[str | bytes, str]:
    """A mutated ``text`` of format ``fmt`` and a description of the mutation."""
    kind = draw(st.sampled_from(("structured", "structured", "structured", "bytes")))
    if kind == "bytes":
        return _mutate_bytes(draw, text.encode())
    if fmt == "toml":
        return _mutate_toml(draw, tomllib.loads(text))
    return _mutate_csv(draw, text, ";" if fmt == "ipa" else ",")


def _mutate_bytes(draw: Draw, data: bytes) -> tuple[bytes, str]:
    op = draw(st.sampled_from(("truncate", "insert", "empty")))
    if op == "empty":
        return b"", "empty file"
    at = draw(st.integers(0, len(data)))
    if op == "truncate":
        return data[:at], f"truncated at byte {at}"
    junk = draw(st.sampled_from(GARBAGE))
    return data[:at] + junk + data[at:], f"{junk!r} inserted at byte {at}"


def _paths(node, prefix=()) -> list[tuple]:
    """Every key path into a TOML document (tables and arrays included)."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    out = []
    for key, value in items:
        out.append((*prefix, key))
        out += _paths(value, (*prefix, key))
    return out


def _mutate_toml(draw: Draw, doc: dict) -> tuple[str, str]:
    paths = _paths(doc)
    path = draw(st.sampled_from(paths))
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    # beside a key: an unknown key; beside an array element: the element twice (a seventh joint)
    third = "duplicate" if isinstance(parent, list) else "extra key"
    op = draw(st.sampled_from(("set", "set", "set", "delete", third)))
    where = ".".join(map(str, path))
    if op == "set":
        value = draw(st.sampled_from(TOML_VALUES))
        parent[path[-1]] = value
        what = f"{where} = {value!r}"
    elif op == "delete":
        del parent[path[-1]]
        what = f"{where} deleted"
    elif op == "extra key":
        parent["unknown_key"] = 1.0
        what = f"unknown key beside {where}"
    else:
        parent.append(parent[path[-1]])
        what = f"{where} duplicated"
    return tomli_w.dumps(doc), what


def _mutate_csv(draw: Draw, text: str, sep: str) -> tuple[str, str]:
    rows = list(csv.reader(io.StringIO(text), delimiter=sep))
    r = draw(st.integers(0, len(rows) - 1))
    c = draw(st.integers(0, len(rows[0]) - 1))
    op = draw(st.sampled_from(("cell", "cell", "cell", "cell", "drop column", "keep rows", "short row")))
    if op == "cell":
        value = draw(st.sampled_from(CSV_CELLS))
        rows[r][c] = value
        what = f"row {r} column {c} = {value!r}"
    elif op == "drop column":
        rows = [row[:c] + row[c + 1 :] for row in rows]
        what = f"column {c} dropped"
    elif op == "keep rows":
        rows = rows[: r + 1]
        what = f"only the first {r + 1} lines kept"
    else:
        rows[r] = rows[r][:c]
        what = f"row {r} cut to {c} fields"
    out = io.StringIO()
    csv.writer(out, delimiter=sep, lineterminator="\n").writerows(rows)
    return out.getvalue(), what


# -- one case ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Outcome:
    """What a case did: exit code, stderr (warnings appended as lines), and the contract broken
    (None when it held)."""

    target: str
    mutation: str
    code: int | None
    stderr: str
    violation: str | None


def prepare(kit: Kit, target: Target, case: Path) -> Path:
    """Copy the target's file (or session folder) into ``case``; the path of the file to mutate."""
    case.mkdir(parents=True)
    source = getattr(kit, target.source)
    if target.session_file:
        shutil.copytree(source, case / "session")
        return case / "session" / target.session_file
    shutil.copy(source, case / source.name)
    return case / source.name


def run_case(kit: Kit, target: Target, case: Path, draw: Draw) -> Outcome:
    """Mutate the target's file in a fresh ``case`` folder, run its command, check the contract."""
    path = prepare(kit, target, case)
    mutated, what = mutate(draw, path.read_text(), target.fmt)
    path.write_bytes(mutated if isinstance(mutated, bytes) else mutated.encode())
    before = _snapshot(case / "session")
    code, stderr = _run([str(a) for a in target.argv(kit, case, path)])
    return Outcome(target.name, what, code, stderr, _violation(target, case, code, stderr, before))


def _run(argv: list[str]) -> tuple[int | None, str]:
    """``station.cli.main(argv)`` with stdout and stderr captured; a warning is one more stderr line
    (a fresh process would print it) and an exception escaping main a traceback."""
    err = io.StringIO()
    with (
        warnings.catch_warnings(record=True) as caught,
        contextlib.redirect_stdout(io.StringIO()),
        contextlib.redirect_stderr(err),
    ):
        warnings.simplefilter("always")
        try:
            code = cli.main(argv)
        except BaseException as exc:  # noqa: BLE001 - what a user would see as a traceback
            return None, f"Traceback: {type(exc).__name__}: {exc}"
    lines = err.getvalue() + "".join(f"{w.category.__name__}: {w.message}\n" for w in caught)
    return code, lines


def _violation(target: Target, case: Path, code, stderr: str, before: dict | None) -> str | None:
    if code is None:
        return stderr
    lines = [line for line in stderr.splitlines() if not line.startswith("... ")]  # plan's progress
    if code == 0:
        return f"exit 0 with stderr {stderr!r}" if lines else None
    allowed = (2, 1) if target.reaches_devices else (2,)
    if code not in allowed:
        return f"exit {code}: {stderr!r}"
    if len(lines) != 1 or "Traceback" in stderr:
        return f"exit {code} with {len(lines)} stderr lines: {stderr!r}"
    if code == 1 and not lines[0].startswith("station: device error: "):
        return f"exit 1 but not for the absent devices: {stderr!r}"
    if code == 2:
        written = [name for name in target.outputs if (case / name).exists()]
        if written:
            return f"exit 2 but wrote {written}"
        if target.name.endswith("(resume)") and _snapshot(case / "session") != before:
            return "exit 2 but the session folder changed"
    return None


def _snapshot(folder: Path) -> dict | None:
    return {p.name: p.read_bytes() for p in folder.iterdir()} if folder.is_dir() else None
