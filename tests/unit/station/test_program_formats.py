"""``station program --format krl|rapid|fanuc-ls`` beside ``urscript`` and ``poses-csv``: every
format read back (``sim_fixtures.programs``) has one point per measured target in plan order, the
joints in the controller's convention, the contact pose in the vendor's convention, and no name
can break out of a comment or string. No real controller checked these programs."""

import dataclasses
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import configs
from sim_fixtures.programs import left_out, read_program
from station.cli import main
from station.formats.plan import Plan
from station.formats.tables import Controller
from station.jobs import measurement, programs
from station.jobs.programs.common import Program, fanuc_wpr, kuka_abc, quaternion_wxyz

FORMATS = tuple(programs.FORMATS)
KUKA_LIKE = Controller(joint_sign=[-1, 1, 1, -1, 1, -1], joint_offset_deg=[0.0, -90.0, 90.0, 0.0, 0.0, 180.0])
TARGETS = np.array([70, 10, 50, 20, 80, 30, 60, 40])  # not in row order: the order is the plan's
LINES = np.array([3, 1, 3, 2, 1, 2, 3, 1])


@pytest.fixture(scope="module")
def kuka_like(irb_plan):
    """The IRB 2600 with a KUKA-like joint convention and the measurement of a plan with shuffled
    ids, its first target left out (as one without a stand-off within the joint limits)."""
    robot, plan = irb_plan
    robot = robot.model_copy(update={"controller": KUKA_LIKE})
    plan = Plan(TARGETS, LINES, plan.q_deg, plan.pose, plan.approach)
    found = measurement.measurement(plan, robot, "plan.csv")
    found = dataclasses.replace(found, distance_mm=np.r_[np.nan, found.distance_mm[1:]])
    assert found.skipped.tolist() == [True] + [False] * 7
    return robot, found


def written(fmt, found, robot, folder, name="station_measurement"):
    """Write ``fmt`` for ``found`` into ``folder``; the main file's path and text."""
    out = folder / (name + programs.FORMATS[fmt].extension)
    files = programs.write(fmt, Program(found, robot, "plan.csv", measurement.Motion(), out))
    for path, text in files:
        path.write_text(text)
    return out, files[0][1]


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_has_each_measured_target_in_plan_order_in_the_controllers_convention(
    fmt, kuka_like, tmp_path
):
    robot, found = kuka_like
    out, text = written(fmt, found, robot, tmp_path)
    points = read_program(out, fmt)
    kept = ~found.skipped
    assert [p.target for p in points] == TARGETS[kept].tolist()
    assert [p.line for p in points] == LINES[kept].tolist()
    contact = np.array([p.contact_deg for p in points])
    standoff = np.array([p.standoff_deg for p in points])
    np.testing.assert_allclose(contact, KUKA_LIKE.controller_deg(found.plan.q_deg[kept]), atol=1e-3)
    np.testing.assert_allclose(standoff, KUKA_LIKE.controller_deg(found.standoff_q_deg[kept]), atol=1e-3)
    np.testing.assert_allclose(KUKA_LIKE.model_deg(contact), found.plan.q_deg[kept], atol=1e-3)
    assert np.abs(contact[:, 0] + found.plan.q_deg[kept, 0]).max() < 1e-3  # A1 against the model's
    assert [p.dwell_s for p in points] == [3.0] * len(points)
    if fmt != "poses-csv":  # a CSV has no comments: a left-out target has no row
        assert left_out(text) == [int(TARGETS[0])]


def _rotation(fmt: str, pose: dict) -> Rotation:
    """The contact orientation a format's pose says, by scipy's conventions."""
    if fmt == "krl":
        return Rotation.from_euler("ZYX", [pose["A"], pose["B"], pose["C"]], degrees=True)
    if fmt == "rapid":
        return Rotation.from_quat([pose["q2"], pose["q3"], pose["q4"], pose["q1"]])
    if fmt == "fanuc-ls":
        return Rotation.from_euler("xyz", [pose["W"], pose["P"], pose["R"]], degrees=True)
    return Rotation.from_rotvec([pose["rx_deg"], pose["ry_deg"], pose["rz_deg"]], degrees=True)


POSITION = {"krl": "XYZ", "rapid": "xyz", "fanuc-ls": "XYZ", "urscript": ("x_mm", "y_mm", "z_mm")}
POSITION["poses-csv"] = POSITION["urscript"]
TOLERANCE = {"fanuc-ls": (0.06, 0.02)}  # its comments hold 0.1 mm and 0.01 deg; the others (mm, deg)


@pytest.mark.parametrize("fmt", FORMATS)
def test_each_format_carries_the_contact_pose_in_its_vendors_convention(fmt, kuka_like, tmp_path):
    robot, found = kuka_like
    points = read_program(written(fmt, found, robot, tmp_path)[0], fmt)
    pose = found.pose[~found.skipped]
    mm, deg = TOLERANCE.get(fmt, (1e-3, 1e-3))
    for p, want in zip(points, pose, strict=True):
        np.testing.assert_allclose([p.pose[k] for k in POSITION[fmt]], want[:3], atol=mm)
        turn = _rotation(fmt, p.pose) * Rotation.from_rotvec(want[3:], degrees=True).inv()
        assert np.degrees(turn.magnitude()) < deg
    if fmt == "poses-csv":  # the vendor columns agree with the quaternion the file had already
        for p in points:
            quat = Rotation.from_quat([p.pose["qx"], p.pose["qy"], p.pose["qz"], p.pose["qw"]])
            for key, seq in (("kuka_{}_deg", ("ZYX", "abc")), ("fanuc_{}_deg", ("xyz", "wpr"))):
                angles = [p.pose[key.format(c)] for c in seq[1]]
                assert (Rotation.from_euler(seq[0], angles, degrees=True) * quat.inv()).magnitude() < 1e-5


def test_the_vendor_pose_conventions_on_known_turns_and_round_trips():
    z90 = Rotation.from_euler("z", 90, degrees=True).as_rotvec(degrees=True)
    np.testing.assert_allclose(kuka_abc(z90), [90, 0, 0], atol=1e-9)  # A about z
    np.testing.assert_allclose(fanuc_wpr(z90), [0, 0, 90], atol=1e-9)  # R about z
    x30 = Rotation.from_euler("x", 30, degrees=True).as_rotvec(degrees=True)
    np.testing.assert_allclose(kuka_abc(x30), [0, 0, 30], atol=1e-9)  # C about x''
    np.testing.assert_allclose(fanuc_wpr(x30), [30, 0, 0], atol=1e-9)  # W about x
    np.testing.assert_allclose(quaternion_wxyz(z90), [np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)], atol=1e-12)
    # intrinsic Z-Y'-X'' is not the fixed-axis x-y-z order read the other way round by accident:
    turned = Rotation.from_euler("ZYX", [20, 30, 40], degrees=True).as_rotvec(degrees=True)
    np.testing.assert_allclose(kuka_abc(turned), [20, 30, 40], atol=1e-9)
    np.testing.assert_allclose(fanuc_wpr(turned), [40, 30, 20], atol=1e-9)
    many = Rotation.random(200, random_state=1)
    rotvec = many.as_rotvec(degrees=True)
    back = Rotation.from_euler("xyz", fanuc_wpr(rotvec), degrees=True)
    assert (back * many.inv()).magnitude().max() < 1e-9
    back = Rotation.from_euler("ZYX", kuka_abc(rotvec), degrees=True)
    assert (back * many.inv()).magnitude().max() < 1e-9
    quat = quaternion_wxyz(rotvec)
    assert (quat[:, 0] >= 0).all()
    assert (Rotation.from_quat(quat[:, [1, 2, 3, 0]]) * many.inv()).magnitude().max() < 1e-9


EVIL = 'IRB\nPTP XT10_ON\r"; MoveAbsJ t10_on, v1000, fine, tool0; ! x ;\nJ P[1] 100% FINE ;\\"\x1b'
COMMENT = {"krl": ";", "rapid": "!", "fanuc-ls": "!", "urscript": "#"}
RAPID_STRING = re.compile(r'^  CONST string station_robot := "(?:[^"\\]|""|\\\\)*";$')


def _code(fmt: str, text: str) -> list[str]:
    """The lines of a program that are not comments (Fanuc's line numbers and line count left
    out), and the RAPID string that names the robot checked and left out."""
    code = []
    for line in text.splitlines():
        body = re.sub(r"^\s*\d+:\s*", "", line).strip()
        if body.startswith(COMMENT[fmt]):
            if fmt == "fanuc-ls":  # a ; ends a TP line: only the comment's own end
                assert body.count(";") == 1 and body.endswith(" ;"), line
            continue
        if fmt == "rapid" and body.startswith("CONST string station_robot"):
            assert RAPID_STRING.match(line), line
            continue
        if not body.startswith("LINE_COUNT"):
            code.append(body)
    return code


@pytest.mark.parametrize("fmt", ["krl", "rapid", "fanuc-ls", "urscript"])
def test_a_name_with_line_breaks_and_quotes_stays_in_its_comment_or_string(fmt, kuka_like, tmp_path):
    """The robot's name (and the plan's) reach each program's comments, RAPID's also a string: with
    line breaks, quotes, statement ends and code in them, the program's code is what it was."""
    robot, found = kuka_like
    texts = []
    for k, name in enumerate(("IRB", EVIL)):
        (tmp_path / str(k)).mkdir()
        out, text = written(fmt, found, robot.model_copy(update={"name": name}), tmp_path / str(k))
        texts.append(text + (out.with_suffix(".dat").read_text() if fmt == "krl" else ""))
    assert "\r" not in texts[1] and "\x1b" not in texts[1]
    assert _code(fmt, texts[1]) == _code(fmt, texts[0])
    assert "XT10_ON" in texts[1] and "MoveAbsJ t10_on" in texts[1]  # there, in a comment


def test_krl_writes_the_src_and_its_dat_and_refuses_names_krl_cannot_take(irb_plan, tmp_path, capsys):
    robot, plan = irb_plan
    path = tmp_path / "plan.csv"
    path.write_text(plan.csv_text())
    irb = str(configs.path("robots/abb_irb2600.toml"))

    def program(fmt, out):
        return main(["program", str(path), "--robot", irb, "--format", fmt, "--out", str(tmp_path / out)])

    assert program("krl", "station_measurement.src") == 0
    assert "wrote " + str(tmp_path / "station_measurement.src") in capsys.readouterr().out
    src, dat = ((tmp_path / f"station_measurement.{s}").read_text() for s in ("src", "dat"))
    assert "DEF station_measurement( )" in src and "DEFDAT station_measurement" in dat
    refused = {
        ("krl", "1st_pass.src"): "module name '1st_pass' (from the file name) must be a KRL name",
        ("krl", "a" * 25 + ".src"): "must be a KRL name",
        ("krl", "measure.txt"): "krl writes a .src and its .dat: name the .src file",
        ("fanuc-ls", "my-pass.ls"): "program name 'MY-PASS' (from the file name) must be a TP program name",
        ("fanuc-ls", "p" * 37 + ".ls"): "must be a TP program name",
    }
    for (fmt, out), said in refused.items():
        assert program(fmt, out) == 2
        err = capsys.readouterr().err
        assert said in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / out).exists() and not (tmp_path / out).with_suffix(".dat").exists()
    assert program("fanuc-ls", "second_pass.ls") == 0
    assert (tmp_path / "second_pass.ls").read_text().startswith("/PROG  SECOND_PASS\n")


def test_the_robot_files_controller_convention_reaches_the_program(irb_plan, tmp_path):
    robot, plan = irb_plan
    path, robot_file, out = tmp_path / "plan.csv", tmp_path / "kuka_like.toml", tmp_path / "pass.src"
    path.write_text(plan.csv_text())
    convention = f"joint_sign = {KUKA_LIKE.joint_sign}\njoint_offset_deg = {KUKA_LIKE.joint_offset_deg}\n"
    robot_file.write_text(
        configs.path("robots/abb_irb2600.toml").read_text() + "\n[controller]\n" + convention
    )
    argv = ["program", str(path), "--robot", str(robot_file), "--format", "krl", "--out", str(out)]
    assert main(argv) == 0
    contact = [p.contact_deg for p in read_program(out, "krl")]
    np.testing.assert_allclose(contact, KUKA_LIKE.controller_deg(plan.q_deg), atol=1e-3)
