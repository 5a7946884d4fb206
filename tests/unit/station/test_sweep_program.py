"""``station program`` on a sweep plan: per pass, in every vendor format, a joint move to the first
waypoint's stand-off, a linear move onto it, linear moves through the waypoints blended at each but
the last (the contact kept along the edge), a linear move back from the last; the joints in the
controller's convention, the tool the ball. Read here by the blend syntax each writer documents."""

import dataclasses

import numpy as np
import pytest

from sim_fixtures.programs import read_sweep
from station.cli import main
from station.formats.plan import load_plan
from station.formats.tables import Controller
from station.jobs import measurement, programs
from station.jobs.programs.common import Program

KUKA_LIKE = Controller(joint_sign=[-1, 1, 1, -1, 1, -1], joint_offset_deg=[0.0, -90.0, 90.0, 0.0, 0.0, 180.0])
PASSES = np.array([4, 4, 4, 4, 9, 9, 9, 9])  # two passes of four waypoints, ids not from 0


@pytest.fixture(scope="module")
def sweep(irb_plan):
    """The IRB 2600 with a KUKA-like convention and a 50 mm ball, and the measurement of a sweep
    plan of two passes along one gauge line."""
    robot, plan = irb_plan
    robot = robot.model_copy(update={"controller": KUKA_LIKE, "tool_mm": [0.0, 0.0, 50.0]})
    from station.jobs.planning import contact_poses

    plan = dataclasses.replace(plan, pose=contact_poses(robot, np.radians(plan.q_deg)), sweep_pass=PASSES)
    return robot, measurement.measurement(plan, robot, "plan.csv")


FORMATS = ("urscript", "krl", "rapid", "fanuc-ls", "poses-csv")


def _written(fmt, robot, found, folder):
    """The program of ``found`` in ``fmt``, written into ``folder``: its main file's path."""
    out = folder / ("station_measurement" + programs.FORMATS[fmt].extension)
    for path, text in programs.write(fmt, Program(found, robot, "plan.csv", measurement.Motion(), out)):
        path.write_text(text)
    return out


@pytest.mark.parametrize("fmt", FORMATS)
def test_each_pass_is_one_blended_linear_sweep_through_its_waypoints(fmt, sweep, tmp_path):
    # read as the simulated controller plays it (sim_fixtures.programs.read_sweep checks each
    # pass's moves: joint to the stand-off, linear on, dwell, blended linear moves, linear back)
    robot, found = sweep
    passes = read_sweep(_written(fmt, robot, found, tmp_path), fmt)
    contact = robot.controller.controller_deg(found.plan.q_deg)
    standoff = robot.controller.controller_deg(found.standoff_q_deg)
    rows = found.plan.passes()
    assert [(p.number, p.line, p.targets.tolist()) for p in passes] == [
        (int(found.plan.sweep_pass[r[0]]), int(found.plan.line[r[0]]), found.plan.target[r].tolist())
        for r in rows
    ]
    for p, r in zip(passes, rows, strict=True):  # deg: the joints as written (4 decimals, or 6 in rad)
        np.testing.assert_allclose(p.waypoints_deg, contact[r], atol=1e-3)
        np.testing.assert_allclose(p.standoff_deg, standoff[[r[0], r[-1]]], atol=1e-3)
        assert p.dwell_s == measurement.Motion().dwell_s


@pytest.mark.parametrize(
    ("fmt", "old", "new"),
    [
        ("urscript", ", r=0.0100)", ")"),  # a waypoint not blended: the tool stops mid-pass
        ("krl", "LIN XT4_ON\nWAIT", "LIN XT4_OFF\nWAIT"),  # a pass that does not start on its first waypoint
        ("rapid", "station_sweep, z10", "station_sweep, fine"),
        ("fanuc-ls", "WAIT 3.00(sec)", "WAIT 0.00(sec) ;\n  99:  WAIT 3.00(sec)"),  # a dwell too many
        ("poses-csv", "\n1,0,", "\n1,3,"),  # a pass over two gauge lines
    ],
)
def test_a_sweep_whose_moves_are_not_a_pass_is_refused(fmt, sweep, tmp_path, old, new):
    robot, found = sweep
    path = _written(fmt, robot, found, tmp_path)
    assert old in path.read_text()
    path.write_text(path.read_text().replace(old, new, 1))
    with pytest.raises(ValueError, match=r"^pass \d+: "):
        read_sweep(path, fmt)


def test_the_programs_state_the_sweep_speed_and_the_ball(sweep, tmp_path):
    robot, found = sweep
    mo = measurement.Motion()
    text = {}
    for fmt in FORMATS:
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
    write = ["program", str(plan), "--robot", str(robot), "--format", "urscript", "--out", str(out)]
    assert main([*write, "--sweep"]) == 0  # the contract's spelling
    text = out.read_text()
    assert main(write) == 0 and out.read_text() == text  # the pass column decides without it too
    passes = load_plan(plan).passes()
    assert text.count("  movej(") == len(passes)
    assert text.count(", r=") == sum(len(rows) - 2 for rows in passes)


def test_station_program_sweep_refuses_a_static_plan_in_one_line(tmp_path, capsys):
    import configs

    robot, setup = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")
    plan = tmp_path / "static.csv"
    made = ["plan", "--robot", str(robot), "--setup", str(setup), "--per-line", "20", "--select", "40"]
    assert main([*made, "--out", str(plan), "--no-suggest"]) == 0
    out = tmp_path / "sweep.script"
    capsys.readouterr()
    code = main(
        ["program", str(plan), "--robot", str(robot), "--format", "urscript", "--out", str(out), "--sweep"]
    )
    err = capsys.readouterr().err
    assert (
        code == 2 and err.count("\n") == 1 and "has no pass column" in err and "station plan --sweep" in err
    )
    assert not out.exists()
