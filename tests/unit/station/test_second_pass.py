"""The offline second pass (``station program PLAN --table T``): for a controller without a target
channel, a corrected table brings the tool onto each planned contact at corrected joints, the
stand-offs follow, and the targets a first session left unmeasured come first."""

import csv

import numpy as np
import pytest

import configs
from calib import ik
from sim_fixtures.world import GaugeLine, Robot, World
from station.cli import main
from station.formats.base import toml_text
from station.formats.plan import Plan
from station.formats.session_folder import SAMPLE_COLUMNS
from station.formats.tables import load_robot
from station.jobs.planning import contact_poses, robot_arrays

IRB2600 = configs.path("robots/abb_irb2600.toml")
LINE = GaugeLine(
    0, np.array([1000.0, 0, 300]), np.array([0, 1.0, 0]), 400.0, np.array([0, 0, 1.0]), np.array([0, 0, -1.0])
)
ERRORS = {1: ("a_mm", 1.2), 2: ("d_mm", -0.8), 3: ("theta_deg", 0.05), 4: ("alpha_deg", -0.04)}
"""The true robot's table against the nominal: millimetres and hundredths of a degree, a real arm's."""


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """The IRB 2600's nominal file, a table that is the true robot (a perfect calibration), and a
    12-target plan along one edge."""
    folder = tmp_path_factory.mktemp("second_pass")
    robot = load_robot(IRB2600)
    nominal = Robot(robot.table_deg(), np.zeros(3), robot.limits_deg())
    q, lines = World(nominal, nominal, np.zeros(3), 0.0, (LINE,)).line_configurations(
        12, np.random.default_rng(3), max_tilt_deg=10.0
    )
    plan = Plan(
        np.arange(12) + 100, lines, q, contact_poses(robot, np.radians(q)), np.tile(LINE.approach, (12, 1))
    )
    (folder / "plan.csv").write_text(plan.csv_text())
    truth = robot.model_dump(exclude_none=True)
    for j, (key, change) in ERRORS.items():
        truth["joints"][j][key] += change
    (folder / "truth.toml").write_text(toml_text(truth))
    return folder, plan, load_robot(folder / "truth.toml")


def _program(folder, *extra):
    out = folder / "poses.csv"
    argv = ["program", str(folder / "plan.csv"), "--robot", str(IRB2600), "--format", "poses-csv"]
    assert main([*argv, "--out", str(out), *extra]) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    cols = [f"q{i}_deg" for i in range(1, 7)]
    return (
        rows,
        np.array([[float(r[c]) for c in cols] for r in rows]),
        np.array([[float(r[f"standoff_{c}"]) for c in cols] for r in rows]),
    )


def _true_tcp(table, q_deg):
    dh, tool = robot_arrays(table)
    return ik.tool_frames(dh, np.radians(q_deg), tool)


def test_the_corrected_table_brings_the_true_tool_onto_every_contact(cell, capsys):
    folder, plan, truth = cell
    _, q_first, _ = _program(folder)
    first_off = np.linalg.norm(_true_tcp(truth, q_first)[0] - plan.pose[:, :3], axis=1)
    assert first_off.min() > 0.5  # the nominal joints land millimetres off, as a real robot's do
    rows, q, q_standoff = _program(folder, "--table", str(folder / "truth.toml"))
    said = capsys.readouterr().out
    assert "second pass: 12 of 12 contact joints corrected" in said
    assert [int(r["target"]) for r in rows] == plan.target.tolist()
    p, rot = _true_tcp(truth, q)
    np.testing.assert_allclose(
        p, plan.pose[:, :3], atol=1e-3
    )  # the solver's tolerance, not the robot's error
    approach = np.array([[float(r[c]) for c in ("ax", "ay", "az")] for r in rows])
    back = _true_tcp(truth, q_standoff)[0] - p  # the stand-off lies back along the approach, as before
    np.testing.assert_allclose(back / np.linalg.norm(back, axis=1)[:, None], -approach, atol=1e-4)


def _session(folder, targets):
    session = folder / "first_pass"
    session.mkdir(exist_ok=True)
    (session / "session.toml").write_text("started_utc = '2026-11-27T00:00:00Z'\n")
    rows = [",".join(SAMPLE_COLUMNS)]
    for k, t in enumerate(targets):
        rows.append(f"{k},{t},0,0,0,0,0,0,0,1000.0,,{k}.0,0,0,,1.5,{k}.0")
    (session / "samples.csv").write_text("\n".join(rows) + "\n")
    return session


def test_the_targets_a_first_pass_left_go_first(cell, capsys):
    folder, plan, _ = cell
    measured = [100, 101, 104, 105, 106, 107, 108, 110]
    session = _session(folder, measured)
    rows, _, _ = _program(folder, "--table", str(folder / "truth.toml"), "--session", str(session))
    order = [int(r["target"]) for r in rows]
    assert order == [102, 103, 109, 111, *measured]
    assert f"4 targets not measured in {session} first, then the 8 measured" in capsys.readouterr().out


def test_a_session_of_another_plan_or_without_a_table_is_refused(cell, capsys):
    folder, _, _ = cell
    argv = ["program", str(folder / "plan.csv"), "--robot", str(IRB2600), "--format", "poses-csv"]
    out = folder / "refused.csv"
    other = _session(folder, [100, 7])
    assert (
        main([*argv, "--out", str(out), "--table", str(folder / "truth.toml"), "--session", str(other)]) == 2
    )
    assert "measured target 7, which" in capsys.readouterr().err
    assert main([*argv, "--out", str(out), "--session", str(other)]) == 2
    assert "--session goes with --table" in capsys.readouterr().err
    assert not out.exists()
