"""``station program`` on a sweep plan: per pass, in every vendor format, a joint move to the first
waypoint's stand-off, a linear move onto it, linear moves through the waypoints blended at each but
the last (the contact kept along the edge), a linear move back from the last; the joints in the
controller's convention, the tool the ball. Read here by the blend syntax each writer documents."""

import dataclasses
import re

import numpy as np
import pytest

from station.cli import main
from station.formats.plan import load_plan
from station.formats.tables import Controller
from station.jobs import measurement, programs
from station.jobs.programs.common import Program

KUKA_LIKE = Controller(joint_sign=[-1, 1, 1, -1, 1, -1], joint_offset_deg=[0.0, -90.0, 90.0, 0.0, 0.0, 180.0])
PASSES = np.array([4, 4, 4, 4, 9, 9, 9, 9])  # two passes of four waypoints, ids not from 0
N = r"[-+0-9.eE]+"


@pytest.fixture(scope="module")
def sweep(irb_plan):
    """The IRB 2600 with a KUKA-like convention and a 50 mm ball, and the measurement of a sweep
    plan of two passes along one gauge line."""
    robot, plan = irb_plan
    robot = robot.model_copy(update={"controller": KUKA_LIKE, "tool_mm": [0.0, 0.0, 50.0]})
    from station.jobs.planning import contact_poses

    plan = dataclasses.replace(plan, pose=contact_poses(robot, np.radians(plan.q_deg)), sweep_pass=PASSES)
    return robot, measurement.measurement(plan, robot, "plan.csv")


def _urscript(text, folder):
    moves = []
    for kind, joints, rest in re.findall(r"^  (movej|movel)\(\[([^\]]*)\](.*)$", text, re.M):
        q = np.degrees([float(v) for v in joints.split(",")])
        moves.append((kind == "movej", q, ", r=" in rest))
    return moves


def _krl(text, folder):
    dat = (folder / "station_measurement.dat").read_text()
    axes = {
        name: np.array([float(v) for v in re.findall(rf"\bA[1-6] ({N})", body)])
        for name, body in re.findall(r"^DECL E6AXIS (\w+)=\{([^}]*)\}", dat, re.M)
    }
    found = re.findall(r"^(PTP|LIN) (\w+)( C_DIS)?$", text, re.M)
    return [(kind == "PTP", axes[name], bool(blend)) for kind, name, blend in found]


def _rapid(text, folder):
    targets = {
        name: np.array([float(v) for v in joints.split(",")])
        for name, joints in re.findall(r"CONST jointtarget (\w+) := \[\[([^\]]*)\]", text)
    }
    found = re.findall(
        r"^    (MoveAbsJ (\w+)|MoveL CalcRobT\((\w+), station_ball\)), \w+, (\w+), (\w+);", text, re.M
    )
    assert {tool for *_, tool in found} == {"station_ball"}
    return [(bool(j), targets[j or lin], zone != "fine") for _, j, lin, zone, _ in found]


def _fanuc(text, folder):
    pos = {
        int(n): np.array([float(v) for v in re.findall(rf"J[1-6]=\s*({N}) deg", body)])
        for n, body in re.findall(r'^P\[(\d+):"[^"]*"\]\{(.*?)\};', text, re.M | re.S)
    }
    found = re.findall(r"^\s*\d+:  ([JL]) P\[(\d+)\] .* (FINE|CNT100) ;$", text, re.M)
    return [(kind == "J", pos[int(n)], term == "CNT100") for kind, n, term in found]


READERS = {"urscript": _urscript, "krl": _krl, "rapid": _rapid, "fanuc-ls": _fanuc}


@pytest.mark.parametrize("fmt", tuple(READERS))
def test_each_pass_is_one_blended_linear_sweep_through_its_waypoints(fmt, sweep, tmp_path):
    robot, found = sweep
    out = tmp_path / ("station_measurement" + programs.FORMATS[fmt].extension)
    files = programs.write(fmt, Program(found, robot, "plan.csv", measurement.Motion(), out))
    for path, text in files:
        path.write_text(text)
    moves = READERS[fmt](files[0][1], tmp_path)
    contact = robot.controller.controller_deg(found.plan.q_deg)
    standoff = robot.controller.controller_deg(found.standoff_q_deg)
    expected = []
    for rows in found.plan.passes():
        expected += [(True, standoff[rows[0]], False), (False, contact[rows[0]], False)]
        expected += [(False, contact[k], k != rows[-1]) for k in rows[1:]]
        expected += [(False, standoff[rows[-1]], False)]
    assert [(j, b) for j, _, b in moves] == [(j, b) for j, _, b in expected]
    error = np.array([q - e for (_, q, _), (_, e, _) in zip(moves, expected, strict=True)])
    assert np.abs(error).max() < 1e-3  # deg: the joints as written (4 decimals, or 6 in rad)


def test_the_programs_state_the_sweep_speed_and_the_ball(sweep, tmp_path):
    robot, found = sweep
    mo = measurement.Motion()
    text = {}
    for fmt in READERS:
        out = tmp_path / ("station_measurement" + programs.FORMATS[fmt].extension)
        text[fmt] = programs.write(fmt, Program(found, robot, "plan.csv", mo, out))[0][1]
    assert f"v={mo.sweep_mm_s / 1000:.4f}, r={mo.blend_mm / 1000:.4f})" in text["urscript"]
    assert "set_tcp(p[0.000000, 0.000000, 0.050000, 0, 0, 0])" in text["urscript"]
    assert (
        f"$VEL.CP = {mo.sweep_mm_s / 1000:.4f}" in text["krl"] and "$TOOL = {X 0, Y 0, Z 50," in text["krl"]
    )
    assert f"$APO.CDIS = {mo.blend_mm:g}" in text["krl"]
    assert f"station_sweep := [{mo.sweep_mm_s:g}, {mo.sweep_deg_s:g}," in text["rapid"]
    assert "station_ball := [TRUE, [[0.000, 0.000, 50.000]" in text["rapid"]
    assert (
        f"{mo.sweep_mm_s:g}mm/sec CNT100" in text["fanuc-ls"] and "UTOOL 1: X 0 Y 0 Z 50" in text["fanuc-ls"]
    )


def test_station_program_writes_a_sweep_plan_from_station_plan_sweep(tmp_path, capsys):
    import configs

    robot, setup = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")
    plan = tmp_path / "sweep.csv"
    assert main(["plan", "--robot", str(robot), "--setup", str(setup), "--sweep", "--out", str(plan)]) == 0
    out = tmp_path / "sweep.script"
    assert main(["program", str(plan), "--robot", str(robot), "--format", "urscript", "--out", str(out)]) == 0
    text = out.read_text()
    passes = load_plan(plan).passes()
    assert text.count("  movej(") == len(passes)
    assert text.count(", r=") == sum(len(rows) - 2 for rows in passes)
