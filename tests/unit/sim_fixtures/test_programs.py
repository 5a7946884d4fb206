"""``sim_fixtures.programs``: the readers a simulated controller runs the station's programs with
check each target's moves, so a program that moves in another order is not read as a good one."""

from pathlib import Path

import numpy as np
import pytest

from sim_fixtures.programs import read_fanuc_ls, read_krl, read_rapid, read_urscript
from station.formats.plan import Plan
from station.formats.tables import Joint, RobotFile
from station.jobs import measurement, programs
from station.jobs.programs.common import Program

Q = np.array([[10.0, -80.0, 100.0, 5.0, 60.0, 15.0], [-20.0, -70.0, 95.0, -5.0, 50.0, -30.0]])


@pytest.fixture(scope="module")
def texts():
    """Each format's text(s) for a two-target plan on a simple arm."""
    rows = [(0, 90, 0, 400), (0, 0, 600, 0), (0, 90, 100, 0), (0, -90, 0, 600), (0, 90, 0, 0), (0, 0, 0, 100)]
    joints = [Joint(theta_deg=t, alpha_deg=al, a_mm=a, d_mm=d) for t, al, a, d in rows]
    robot = RobotFile(name="arm", joints=joints)
    found = measurement.measurement(Plan(np.array([4, 9]), np.array([1, 2]), Q), robot, "plan.csv")
    out = {}
    for fmt, name in (("krl", "p.src"), ("rapid", "p.mod"), ("fanuc-ls", "p.ls"), ("urscript", "p.script")):
        files = programs.write(fmt, Program(found, robot, "plan.csv", measurement.Motion(), Path(name)))
        out[fmt] = [text for _, text in files]
    return out


def test_the_readers_read_what_the_writers_wrote(texts):
    for points in (
        read_krl(*texts["krl"]),
        read_rapid(*texts["rapid"]),
        read_fanuc_ls(*texts["fanuc-ls"]),
        read_urscript(*texts["urscript"]),
    ):
        assert [(p.target, p.line) for p in points] == [(4, 1), (9, 2)]
        np.testing.assert_allclose([p.contact_deg for p in points], Q, atol=1e-3)


@pytest.mark.parametrize(
    ("fmt", "reader", "old", "new"),
    [
        ("krl", read_krl, "LIN XT9_ON", "LIN XT9_OFF"),  # never onto the contact
        ("krl", read_krl, "WAIT SEC 3\n", ""),  # no dwell
        ("rapid", read_rapid, "    MoveL CalcRobT(contact", "    MoveL CalcRobT(standoff"),
        ("fanuc-ls", read_fanuc_ls, "J P[3] 10% FINE", "J P[4] 10% FINE"),  # the joint move to the contact
        ("urscript", read_urscript, "  sleep(3)\n", ""),
    ],
)
def test_a_program_whose_moves_are_not_the_measurement_is_refused(texts, fmt, reader, old, new):
    first, *rest = texts[fmt]
    assert old in first
    with pytest.raises(ValueError, match="target|station_target"):
        reader(first.replace(old, new), *rest)
