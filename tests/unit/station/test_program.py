"""``station program``: plan rows carry the contact pose and approach (older plans still read), and
the measurement program moves to a stand-off on the approach, slowly onto the contact, dwells and
retreats, each pose where the nominal model puts it."""

import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import configs
from calib import ik
from errors import InputError
from station.cli import main
from station.formats.plan import Plan, load_plan
from station.formats.tables import load_robot
from station.jobs import measurement, programs
from station.jobs.planning import contact_poses, robot_arrays
from station.jobs.programs.common import Program

IRB2600 = configs.path("robots/abb_irb2600.toml")


def test_plan_rows_carry_the_contact_pose_and_older_plans_still_read(irb_plan, tmp_path):
    robot, plan = irb_plan
    path = tmp_path / "plan.csv"
    path.write_text(plan.csv_text())
    header = path.read_text().splitlines()[0]
    assert header.endswith("x_mm,y_mm,z_mm,rx_deg,ry_deg,rz_deg,ax,ay,az")
    back = load_plan(path)
    np.testing.assert_allclose(back.pose, plan.pose, atol=1e-4)
    np.testing.assert_allclose(back.approach, plan.approach, atol=1e-6)
    old = Plan(plan.target, plan.line, plan.q_deg)  # a plan of joints only, as before
    path.write_text(old.csv_text())
    assert load_plan(path).pose is None and load_plan(path).approach is None
    text = plan.csv_text().splitlines()
    path.write_text("\n".join([text[0].replace(",az", ""), *(r.rsplit(",", 1)[0] for r in text[1:])]) + "\n")
    with pytest.raises(InputError, match="has x_mm but not az: a contact pose needs all of"):
        load_plan(path)
    path.write_text("\n".join([text[0], text[1].rsplit(",", 1)[0] + ",-2.0"]) + "\n")
    with pytest.raises(InputError, match=r"row 0 \(line 2\): az: '-2.0' is outside -1.5 .. 1.5"):
        load_plan(path)
    path.write_text("\n".join([text[0], text[1].rsplit(",", 1)[0] + ",-0.5"]) + "\n")
    with pytest.raises(InputError, match=r"row 0 \(line 2\): ax,ay,az: not a unit direction"):
        load_plan(path)


def program_text_of(fmt: str, found, robot) -> str:
    """The text of the first file ``station program --format fmt`` writes for ``found``."""
    return programs.write(
        fmt,
        Program(
            found, robot, "plan.csv", measurement.Motion(), Path("prog" + programs.FORMATS[fmt].extension)
        ),
    )[0][1]


def _tcp(robot, q_deg):
    dh, tool = robot_arrays(robot)
    return ik.tool_frames(dh, np.radians(np.atleast_2d(q_deg)), tool)


def test_the_program_backs_off_along_the_approach_and_comes_back_onto_the_contact(irb_plan):
    robot, plan = irb_plan
    found = measurement.measurement(plan, robot, "plan.csv")
    p_contact, r_contact = _tcp(robot, plan.q_deg)
    p_off, r_off = _tcp(robot, found.standoff_q_deg)
    np.testing.assert_allclose(p_contact, plan.pose[:, :3], atol=1e-6)
    np.testing.assert_allclose(p_off, p_contact - found.distance_mm[:, None] * plan.approach, atol=1e-4)
    np.testing.assert_allclose(r_off, r_contact, atol=1e-6)  # the same tool orientation
    assert (found.distance_mm == 20.0).all()

    script = program_text_of("urscript", found, robot)
    moves = run_urscript(script, {}, {})  # registers at power-on: no corrected target
    assert [m[0] for m in moves] == ["movej", "movel", "sleep", "movel"] * len(plan)
    joints = [np.degrees(m[1]) for m in moves if m[0] != "sleep"]
    for k in range(len(plan)):
        off, contact, back = joints[3 * k : 3 * k + 3]
        np.testing.assert_allclose(off, found.standoff_q_deg[k], atol=1e-4)  # 1e-6 rad written
        np.testing.assert_allclose(contact, plan.q_deg[k], atol=1e-4)  # 1e-6 rad written
        np.testing.assert_allclose(back, found.standoff_q_deg[k], atol=1e-4)  # 1e-6 rad written
    assert script.count("sleep(3)") == len(plan) and "v=0.0050" in script  # 5 mm/s onto the edge

    rows = program_text_of("poses-csv", found, robot).splitlines()
    assert rows[0].split(",")[:9] == [
        "target",
        "line",
        "x_mm",
        "y_mm",
        "z_mm",
        "rx_deg",
        "ry_deg",
        "rz_deg",
        "qw",
    ]
    first = np.array(rows[1].split(","), float)
    w, x, y, z = first[8:12]
    np.testing.assert_allclose(Rotation.from_quat([x, y, z, w]).as_matrix(), r_contact[0], atol=1e-6)


def run_urscript(script: str, ints: dict, floats: dict) -> list[tuple[str, object]]:
    """Run a generated URScript as Python: its blocks are indented and closed by ``end`` lines
    (dropped), ``p[...]`` is a pose (a list); the input registers read ``ints`` and ``floats`` (by
    number, 0 where not set, as at power-on) and every move or sleep is recorded with its first
    argument."""
    moves = []

    def record(name):
        return lambda first, **_: moves.append((name, first))

    env = {
        "read_input_integer_register": lambda r: ints.get(r, 0),
        "read_input_float_register": lambda r: floats.get(r, 0.0),
        "set_tcp": lambda pose: None,
        **{name: record(name) for name in ("movej", "movel", "sleep")},
    }
    lines = [line for line in script.splitlines() if line.strip() != "end"]
    exec(re.sub(r"\bp\[", "[", "\n".join(lines)), env)  # noqa: S102 - the script under test
    return moves


def test_the_program_moves_to_the_corrected_target_the_registers_name_and_only_that(irb_plan):
    robot, plan = irb_plan
    found = measurement.measurement(plan, robot, "plan.csv")
    script = program_text_of("urscript", found, robot)
    k = 3
    change = np.radians([0.2, -0.1, 0.15, -0.3, 0.25, 0.35])  # a correction of a few tenths of a degree
    corrected = np.radians(plan.q_deg[k]) + change
    floats = {42 + i: float(v) for i, v in enumerate(corrected[:5])}
    ints = {42: int(plan.target[k]) + 1, 43: round(corrected[5] * 1e6)}  # what RtdeTargets writes
    moves = [m for m in run_urscript(script, ints, floats) if m[0] != "sleep"]
    joints = np.degrees([m[1] for m in moves]).reshape(len(plan), 3, 6)
    np.testing.assert_allclose(joints[k, 1], np.degrees(corrected), atol=1e-4)  # joint 6: 1 urad written
    for step in (0, 2):  # the stand-off moves with the contact
        np.testing.assert_allclose(joints[k, step], found.standoff_q_deg[k] + np.degrees(change), atol=1e-4)
    others = np.arange(len(plan)) != k
    np.testing.assert_allclose(joints[others, 1], plan.q_deg[others], atol=1e-4)
    np.testing.assert_allclose(joints[others, 0], found.standoff_q_deg[others], atol=1e-4)
    ints[42] = int(plan.target[k])  # the index register naming the target before (index + 1 = k)
    moves = [m for m in run_urscript(script, ints, floats) if m[0] == "movel"]
    np.testing.assert_allclose(np.degrees(moves[2 * k][1]), plan.q_deg[k], atol=1e-4)
    assert np.degrees(np.abs(np.array(moves[2 * (k - 1)][1]) - np.radians(plan.q_deg[k - 1]))).max() > 0.1


def test_a_plan_for_another_robot_is_refused_naming_the_target(irb_plan, tmp_path, capsys):
    robot, plan = irb_plan
    ur10 = load_robot(configs.path("robots/ur10.toml"))
    with pytest.raises(InputError, match=r"^plan.csv: target \d+: its contact pose lies .* from UR10"):
        measurement.measurement(plan, ur10, "plan.csv")
    path = tmp_path / "plan.csv"
    path.write_text(Plan(plan.target, plan.line, plan.q_deg).csv_text())  # an older plan: the nominal TCP
    out = tmp_path / "prog.script"
    assert (
        main(["program", str(path), "--robot", str(IRB2600), "--format", "urscript", "--out", str(out)]) == 0
    )
    assert "the nominal TCP at the plan's joints" in capsys.readouterr().out
    assert out.read_text().count("movej(") == len(plan)


def test_a_target_without_a_stand_off_within_the_limits_is_left_out_and_said(irb_plan):
    robot, plan = irb_plan
    q3 = float(plan.q_deg[0, 2])
    joints = [j.model_copy() for j in robot.joints]
    joints[2] = joints[2].model_copy(update={"q_min_deg": q3 - 1e-4, "q_max_deg": q3 + 1e-4})
    pinned = robot.model_copy(update={"joints": joints})  # joint 3 cannot move from target 0's angle
    found = measurement.measurement(plan, pinned, "plan.csv")
    assert found.skipped[0]
    script = program_text_of("urscript", found, pinned)
    assert "# target 0 left out: no stand-off within the joint limits" in script
    assert script.count("movej(") == int((~found.skipped).sum())
    rows = program_text_of("poses-csv", found, robot).splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == plan.target[~found.skipped].tolist()


def test_names_with_line_breaks_cannot_inject_code_into_the_program(irb_plan, tmp_path):
    """A robot named, or a plan file named, with a line break and code after it: the name goes into
    the program's header comment; every line before ``def station_measurement():`` stays a comment."""
    robot, plan = irb_plan
    text = IRB2600.read_text().replace(
        'name = "ABB IRB 2600-20/1.65"',
        'name = "IRB\\nmovej([0, 0, 0, 0, 0, 0])\\npopup(\\"\\u001b[31mhi\\")"',
    )
    named = tmp_path / "robot.toml"
    named.write_text(text)
    path = tmp_path / "plan\nmovej([1, 1, 1, 1, 1, 1]).csv"
    path.write_text(plan.csv_text())
    out = tmp_path / "prog.script"
    assert main(["program", str(path), "--robot", str(named), "--format", "urscript", "--out", str(out)]) == 0
    script = out.read_text()
    head = script[: script.index("def station_measurement():")].splitlines()
    assert all(line.startswith("#") for line in head), head
    assert "\x1b" not in script and "IRB\\nmovej([0, 0, 0, 0, 0, 0])\\npopup" in head[0]
    assert sum(line.lstrip().startswith("movej(") for line in script.splitlines()) == len(plan)


def test_a_plan_row_whose_orientation_disagrees_with_its_joints_is_refused(irb_plan, tmp_path, capsys):
    """Only the position was compared: a row turned 90 deg about x was accepted, and the slow linear
    approach onto it turned the wrist on the way in."""
    robot, plan = irb_plan
    pose = plan.pose.copy()
    pose[3, 3:] = (
        Rotation.from_rotvec([90.0, 0, 0], degrees=True) * Rotation.from_rotvec(pose[3, 3:], degrees=True)
    ).as_rotvec(degrees=True)
    path = tmp_path / "plan.csv"
    path.write_text(Plan(plan.target, plan.line, plan.q_deg, pose, plan.approach).csv_text())
    out = tmp_path / "prog.script"
    assert (
        main(["program", str(path), "--robot", str(IRB2600), "--format", "urscript", "--out", str(out)]) == 2
    )
    err = capsys.readouterr().err
    assert f"target {int(plan.target[3])}: its contact orientation" in err and "90.0 deg" in err
    assert not out.exists()
    small = plan.pose.copy()  # a robot's own error turns the tool a fraction of a degree: accepted
    small[3, 3:] = (
        Rotation.from_rotvec([0.5, 0, 0], degrees=True) * Rotation.from_rotvec(small[3, 3:], degrees=True)
    ).as_rotvec(degrees=True)
    path.write_text(Plan(plan.target, plan.line, plan.q_deg, small, plan.approach).csv_text())
    assert (
        main(["program", str(path), "--robot", str(IRB2600), "--format", "urscript", "--out", str(out)]) == 0
    )


def test_a_verification_plan_carries_its_contact_poses_into_the_program(tmp_path, capsys):
    """``station program`` called a plan ``station plan --verify`` had just written 'an older plan':
    that plan carried no contact poses."""
    plan, out = tmp_path / "check.csv", tmp_path / "check.script"
    robot, setup = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")
    argv = ["plan", "--verify", "12", "--robot", str(robot), "--setup", str(setup), "--out", str(plan)]
    assert main(argv) == 0
    written = load_plan(plan)
    assert written.pose is not None and written.approach is not None
    nominal = contact_poses(load_robot(robot), np.radians(written.q_deg))
    np.testing.assert_allclose(written.pose, nominal, atol=1e-3)
    capsys.readouterr()
    assert main(["program", str(plan), "--robot", str(robot), "--format", "urscript", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "contact poses from the plan" in said and "older plan" not in said
