"""A user with an arm in Craig's modified D-H, as issue 35 met it (items 5, 15, 16): calibrate and
verify name every parameter by the robot file's rows (what moved in row 5's a is ``J5.a_mm``, and
no report names row 1's a or alpha, which MDH fixes at 0); V.json says whose robot, when, by which
station and what next; a deliberate verify of the nominal table is listed in the history but leaves
the robot's state with its current (calibrated) table."""

import contextlib
import io
import json
import re
from datetime import datetime

import numpy as np
import pytest
import tomli_w

import configs
from calib.conventions import mdh_from_dh, mdh_name
from calib.params import DH_KEYS, DH_NAMES
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import World
from station import installed_version
from station.cli import main
from station.formats.tables import load_robot

SERIAL = "KR-0042"
MOVED = {"J4.a_mm": 15.0}  # standard row 4's a: the modified table's row 5 (J5.a_mm), 15 tolerances
MDH_NAMES = {mdh_name(name) for name in DH_NAMES}
"""Every table parameter an MDH file has: no J1.a_mm, J1.alpha_deg (fixed at 0); flange.a_mm."""


def _mdh_robot(path) -> None:
    """The JR680's table rewritten in modified D-H (``mdh_from_dh``), as a KUKA-like user's file."""
    jr680 = load_robot(configs.path("robots/hsr_jr680.toml"))
    table, flange = mdh_from_dh(jr680.table_deg())
    joints = [
        {**dict(zip(DH_KEYS, map(float, row), strict=True)), "q_min_deg": lo, "q_max_deg": hi}
        for row, (lo, hi) in zip(table, jr680.limits_deg().tolist(), strict=True)
    ]
    doc = {"name": "KR-like", "serial": SERIAL, "convention": "mdh", "joints": joints}
    path.write_text(
        tomli_w.dumps(doc | {"flange": {"a_mm": float(flange[0]), "alpha_deg": float(flange[1])}})
    )


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A simulated JR680 cell whose row-5 link is 15 mm longer than the MDH file says; calibrated,
    then its corrected table and its nominal file verified on new samples, each with its history
    record; every command's stdout and exit."""
    folder = tmp_path_factory.mktemp("mdh_user")
    robot = folder / "robot.toml"
    _mdh_robot(robot)
    world = World.create(2).changed(MOVED)
    rng = np.random.default_rng(3)
    (folder / "setup.toml").write_text(tomli_w.dumps(setup_dict(world, rng)))
    world.sample_set(40, rng).to_csv(folder / "train.csv")
    world.sample_set(20, rng).to_csv(folder / "check.csv")
    common = ["--robot", str(robot), "--setup", str(folder / "setup.toml"), "--db", str(folder / "h.sqlite")]
    runs = {
        "calibrate": ["calibrate", str(folder / "train.csv"), "--out", str(folder / "corrected.toml")],
        "verify corrected": ["verify", str(folder / "check.csv"), "--table", str(folder / "corrected.toml")],
        "verify nominal": ["verify", str(folder / "check.csv"), "--table", str(robot)],
    }
    return folder, common, runs


@pytest.fixture(scope="module")
def ran(cell):
    """Each command of ``cell`` run in order, with ``--report``: name -> (exit, stdout, report)."""
    folder, common, runs = cell
    out = {}
    for k, (name, argv) in enumerate(runs.items()):
        report = folder / f"r{k}.json"
        extra = ["--model", "geometric"] if name == "calibrate" else []
        buffer = io.StringIO()
        with contextlib.redirect_stdout(buffer):
            code = main([*argv, *common, *extra, "--report", str(report)])
        out[name] = (code, buffer.getvalue(), json.loads(report.read_text()))
    return out


def _names(text: str) -> set[str]:
    """Every table parameter name a text mentions (``J5.a_mm``, ``flange.alpha_deg``)."""
    return set(re.findall(r"\b(?:J\d|flange)\.(?:theta_deg|d_mm|a_mm|alpha_deg)\b", text))


def test_calibrate_names_what_moved_by_the_modified_tables_row(ran):
    code, out, report = ran["calibrate"]
    assert code == 0, out
    assert report["fit_check"]["excursion"] == "J5.a_mm", report["fit_check"]
    assert any(w.startswith("J5.a_mm moved +1") for w in report["warnings"]), report["warnings"]
    assert "next: check the robot file (J5.a_mm moved" in out
    assert abs(report["parameters"]["J5.a_mm"]["delta"] - 15.0) < 1.0
    assert _names(out + json.dumps(report)) <= MDH_NAMES


def test_verify_names_parameters_by_the_modified_tables_rows(ran):
    code, out, report = ran["verify nominal"]
    assert code == 3, out
    assert report["likely"][0]["param"] == "J5.a_mm"
    assert "most likely moved: J5.a_mm +14." in out
    for name in ("verify corrected", "verify nominal"):
        _, out, report = ran[name]
        shown = _names(out + json.dumps(report))
        assert shown and shown <= MDH_NAMES, (name, shown - MDH_NAMES)


def test_the_verify_report_says_whose_robot_when_by_which_station_and_what_next(ran, cell):
    for name, verdict, kind, advice in (
        ("verify corrected", "holds", "corrected", "keep using the table"),
        ("verify nominal", "drifted", "nominal", "calibrate the robot"),
    ):
        _, out, report = ran[name]
        assert report["verdict"] == verdict and report["table_kind"] == kind
        assert report["robot"] == {"name": "KR-like", "serial": SERIAL, "convention": "mdh"}
        assert datetime.fromisoformat(report["created_utc"]).tzinfo is not None
        assert report["station_version"] == installed_version()
        assert report["next"].startswith(advice)
        assert out.splitlines()[-2] == f"next: {report['next']}"  # then "wrote V.json"
    calibrated = load_robot(cell[0] / "corrected.toml").calibration["date_utc"]
    assert ran["verify corrected"][2]["table_calibrated_utc"] == calibrated
    assert f"(corrected table, calibrated {calibrated})" in ran["verify corrected"][1]
    assert ran["verify nominal"][2]["table_calibrated_utc"] is None
    assert "(nominal table)" in ran["verify nominal"][1]


def test_a_verify_of_the_nominal_table_leaves_the_robots_state_with_its_current_table(ran, cell, capsys):
    folder, _, _ = cell
    db = str(folder / "h.sqlite")
    assert [ran[n][0] for n in ("calibrate", "verify corrected", "verify nominal")] == [0, 0, 3]
    capsys.readouterr()
    assert main(["history", "--db", db, "--json"]) == 0
    (robot,) = json.loads(capsys.readouterr().out)
    assert robot["state"] == "holds" and robot["last_verdict"] == "drifted"
    assert main(["history", "--db", db]) == 0
    assert capsys.readouterr().out.splitlines()[1].rstrip().endswith("holds")
    assert main(["history", SERIAL, "--db", db]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "state: holds (its current table: the table of calibration #1" in lines[0]
    assert "the table of calibration #1" in lines[2] and "not its current table" not in lines[2]
    assert "a nominal table; not its current table: leaves its state" in lines[3]
    assert main(["history", SERIAL, "--db", db, "--json"]) == 0
    records = json.loads(capsys.readouterr().out)["records"]
    assert [(r["judged"][:22], r["current"]) for r in records] == [
        ("the table it wrote", True),
        ("the table of calibrati", True),
        ("a nominal table", False),
    ]


def test_compare_names_the_free_parameters_by_the_modified_tables_rows(cell):
    from station.formats.samples import load_samples
    from station.formats.tables import load_setup
    from station.jobs.comparison import compare

    folder, common, _ = cell
    samples, robot = load_samples(folder / "train.csv"), load_robot(common[1])
    report = compare(samples, robot, load_setup(folder / "setup.toml"), methods=("lmlc",)).report
    assert "J5.a_mm" in report["free"] and set(report["free"]) & {"J1.a_mm", "J1.alpha_deg"} == set()
    assert _names(json.dumps(report["free"])) <= MDH_NAMES
