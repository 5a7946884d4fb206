"""A sweep session's folder (issue 37): samples.csv with a pass column, rows sharing targets, each
pass appended whole with its flagged rows beside, a pass cut on resume; a row naming another pass
than its target's is a one-line error."""

import csv

import numpy as np
import pytest
import tomli_w

from errors import InputError
from station.acquire import runner
from station.formats.plan import Plan
from station.formats.session_folder import FLAGGED_COLUMNS, SWEEP_COLUMNS, check_session_rows
from tests.hostile_inputs import absent_devices

Q = np.tile([10.0, -30.0, 40.0, 0.0, 20.0, 5.0], (4, 1)) + np.arange(4)[:, None]
PLAN = Plan(np.arange(4), np.array([0, 0, 1, 1]), Q, sweep_pass=np.array([0, 0, 1, 1]))


def _row(sample: int, target: int, **extra) -> dict:
    q = {f"q{i + 1}_deg": float(v) for i, v in enumerate(Q[target])}
    line = int(PLAN.line[target])
    row = {"sample": sample, "target": target, "line": line, "pass": line, **q, "length_mm": 900.0}
    return {**row, "dial_mm": 0.1, "t_s": float(sample), "t_wall_s": 1.7e9 + sample, **extra}


@pytest.fixture
def folder(tmp_path):
    config = tmp_path / "station.toml"
    config.write_text(tomli_w.dumps(absent_devices()))
    (tmp_path / "plan.csv").write_text(PLAN.csv_text())
    inputs = runner.new_session(tmp_path / "sess", config, tmp_path / "plan.csv")
    inputs.folder.make()
    return inputs.folder


def _csv(path):
    with path.open(newline="") as fh:
        return list(csv.reader(fh))


def test_a_pass_is_stored_whole_with_its_flagged_rows_beside(folder):
    flagged = [{"reason": "dial off the edge", **_row(0, 1), "speed_mm_s": 40.0}]
    folder.append_rows([_row(0, 0), _row(1, 0), _row(2, 1)], flagged)
    samples, beside = _csv(folder.samples_csv), _csv(folder.flagged_csv)
    assert tuple(samples[0]) == SWEEP_COLUMNS and len(samples) == 4
    assert tuple(beside[0]) == FLAGGED_COLUMNS and beside[1][0] == "dial off the edge"
    check_session_rows(folder.path)  # target 0 twice: a sweep passes it more than once


def test_resume_cuts_the_rows_of_a_pass_not_recorded_finished(folder):
    folder.append_rows([_row(0, 0), _row(1, 1)], [])
    folder.append_rows([_row(2, 2), _row(3, 3)], [])
    folder.update_header(finished_passes=[0])
    folder.release()
    again = runner.resume_session(folder.path, None).folder
    assert again.keep_rows(lambda r: int(r["pass"]) in {0}) == 2
    assert [r[0] for r in _csv(again.samples_csv)[1:]] == ["0", "1"] and again.next_sample == 2


def test_a_row_of_another_pass_than_its_targets_is_a_one_line_error(folder):
    folder.append_rows([_row(0, 2, **{"pass": 0})], [])
    with pytest.raises(InputError) as err:
        check_session_rows(folder.path)
    assert "row 0 (line 2): pass 0, but target 2 is in pass 1 in the plan" in str(err.value)
