"""A robot file in the wrong D-H convention, as a user meets it (issue 35, items 6, 7): `station
plan` names the likely mistake and its fix instead of "move the gauge block", and the modified
table's row-1 refusal says a table with a twist or offset in row 1 is likely standard D-H. Each an
exit 2 with one line and no plan written."""

import re

import numpy as np
import pytest
import tomli_w

import configs
from calib.conventions import mdh_from_dh
from calib.params import DH_KEYS
from station.cli import main
from station.formats.tables import load_robot

SETUP = configs.path("setups/sim.toml")
JR680 = load_robot(configs.path("robots/hsr_jr680.toml"))


def _write(path, table: np.ndarray, convention: str | None) -> None:
    """A robot file of ``table`` (6, 4) [deg, mm] under ``convention`` (None: no key)."""
    joints = [
        {**dict(zip(DH_KEYS, map(float, row), strict=True)), "q_min_deg": lo, "q_max_deg": hi}
        for row, (lo, hi) in zip(table, JR680.limits_deg().tolist(), strict=True)
    ]
    doc = {"name": "KR-like"} | ({"convention": convention} if convention else {}) | {"joints": joints}
    path.write_text(tomli_w.dumps(doc))


def _zeroed() -> np.ndarray:
    """The JR680's standard table with row 1's alpha and a zeroed, as if it were modified D-H."""
    table = JR680.table_deg().copy()
    table[0, 2:] = 0.0
    return table


MDH = mdh_from_dh(JR680.table_deg())[0]
CASES = {
    "modified numbers, no convention": (
        MDH,
        None,
        "of 20 points are reachable: the table is likely modified D-H (it gives "
        'no convention: the default is "dh"); set convention = "mdh" in {robot}',
    ),
    "modified numbers labelled dh": (
        MDH,
        "dh",
        'the table is likely modified D-H (it says convention = "dh"); set convention = "mdh" in {robot}',
    ),
    "standard, row 1 zeroed, labelled dh": (
        _zeroed(),
        "dh",
        "of 20 points are reachable: the table is likely standard D-H with "
        "row 1's twist and offset zeroed as a modified table's; restore row 1's alpha_deg and a_mm from the "
        'data sheet and keep convention = "dh" in {robot}',
    ),
    "standard, row 1 zeroed, labelled mdh": (
        _zeroed(),
        "mdh",
        'restore row 1\'s alpha_deg and a_mm from the data sheet and set convention = "dh" in {robot}',
    ),
}


def _plan(tmp_path, capsys, *flags) -> tuple[int, list[str]]:
    out = tmp_path / "plan.csv"
    code = main(
        ["plan", "--robot", str(tmp_path / "robot.toml"), "--setup", str(SETUP), "--out", str(out), *flags]
    )
    errors = [ln for ln in capsys.readouterr().err.splitlines() if not ln.startswith("... ")]  # progress
    assert not out.exists()
    return code, errors


@pytest.mark.parametrize("case", CASES)
def test_plan_names_the_likely_convention_mistake_and_its_fix(tmp_path, capsys, case):
    table, convention, says = CASES[case]
    _write(tmp_path / "robot.toml", table, convention)
    code, errors = _plan(tmp_path, capsys, "--no-suggest")
    assert code == 2 and len(errors) == 1, errors
    assert "[[lines]] id 0: only 0 of 100 points reachable" in errors[0]
    assert says.format(robot=tmp_path / "robot.toml") in errors[0]
    assert "move the gauge block" not in errors[0]
    _enough_reachable(errors[0])


def test_a_verification_plan_names_it_too(tmp_path, capsys):
    _write(tmp_path / "robot.toml", MDH, None)
    code, errors = _plan(tmp_path, capsys, "--verify")
    assert code == 2 and len(errors) == 1, errors
    says = CASES["modified numbers, no convention"][2].format(robot=tmp_path / "robot.toml")
    assert "no gauge line has 15 reachable points" in errors[0] and says in errors[0]
    _enough_reachable(errors[0])


def _enough_reachable(error: str) -> None:
    """The other reading named reaches at least half the 20 points tried (what it takes to be named;
    how many exactly turns on the IK's last digits)."""
    other = re.search(r'with convention = "(?:mdh|dh)" (\d+) of 20 points are reachable', error)
    assert other is None or int(other[1]) >= 10, error


def test_a_twist_in_row_1_under_mdh_is_said_to_be_likely_standard_dh(tmp_path, capsys):
    _write(tmp_path / "robot.toml", JR680.table_deg(), "mdh")
    code, errors = _plan(tmp_path, capsys)
    assert code == 2 and len(errors) == 1, errors
    assert (
        'joints.0: alpha_deg -90 and a_mm 250 under convention = "mdh": a table whose row 1 holds a twist or '
        'an offset is likely standard D-H: then set convention = "dh"'
    ) in errors[0]
    assert str(tmp_path / "robot.toml") in errors[0] and "Traceback" not in errors[0]
