"""The sweep plan format (issue 37): an optional ``pass`` column, validated with one-line errors,
carried through ``take``, ``csv_text`` and the session header's ``rows``."""

import numpy as np
import pytest

from errors import InputError
from station.formats.plan import Plan, load_plan

HEADER = "target,line,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,pass\n"


def _write(tmp_path, rows):
    path = tmp_path / "plan.csv"
    path.write_text(HEADER + "".join(f"{t},{ln},0,-90,90,0,90,0,{p}\n" for t, ln, p in rows))
    return path


def test_a_sweep_plan_round_trips_through_csv_and_the_session_header(tmp_path):
    plan = load_plan(_write(tmp_path, [(0, 0, 7), (1, 0, 7), (2, 1, 3), (3, 1, 3), (4, 1, 3)]))
    assert plan.is_sweep and plan.sweep_pass.tolist() == [7, 7, 3, 3, 3]
    assert [p.tolist() for p in plan.passes()] == [[0, 1], [2, 3, 4]]
    again = tmp_path / "again.csv"
    again.write_text(plan.csv_text())
    assert load_plan(again).sweep_pass.tolist() == [7, 7, 3, 3, 3]
    back = Plan.from_rows(plan.rows(), "session.toml")
    assert back.sweep_pass.tolist() == [7, 7, 3, 3, 3]
    assert plan.take(np.array([2, 3])).sweep_pass.tolist() == [3, 3]


def test_a_plan_without_the_column_is_static(tmp_path):
    path = tmp_path / "plan.csv"
    path.write_text(HEADER.replace(",pass", "") + "0,0,0,-90,90,0,90,0\n")
    plan = load_plan(path)
    assert not plan.is_sweep and "pass" not in plan.csv_text()
    assert "pass" not in plan.rows()[0] and Plan.from_rows(plan.rows(), "s").sweep_pass is None


@pytest.mark.parametrize(
    "rows, message",
    [
        ([(0, 0, 1), (1, 1, 1)], "row 1 (line 3): line: pass 1 is on line 0 and line 1"),
        ([(0, 0, 1), (1, 0, 2), (2, 0, 1)], "row 2 (line 4): pass: pass 1 resumes after other rows"),
        ([(0, 0, 1), (1, 0, "x")], "row 1 (line 3): pass:"),
        ([(0, 0, 1), (1, 0, -1)], "row 1 (line 3): pass:"),
    ],
)
def test_a_broken_pass_is_a_one_line_error_naming_row_and_column(tmp_path, rows, message):
    with pytest.raises(InputError) as err:
        load_plan(_write(tmp_path, rows))
    assert message in str(err.value) and "\n" not in str(err.value)
