"""The weighting by the model's discrepancy as a user meets it: ``station calibrate`` on a tracker set
whose poses share an error the model cannot express says so in one summary line and the report's
``discrepancy``, and calls the residual beyond the noise the robot's error, not the instruments'
(re-measuring would not help); on a set of table and white noise alone none of it appears."""

import json

import numpy as np

from tests.unit.calib.test_discrepancy import correlated_world
from tests.unit.station.test_position_sets import calibrate, write_position_set


def test_poses_sharing_an_error_are_weighed_together_and_the_report_says_how(tmp_path, capsys):
    samples, _ = correlated_world(5.0, seed=1)
    path = tmp_path / "shared.csv"
    rows = ["sample,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm"]
    rows += [
        ",".join(map(str, [k, *np.degrees(samples.q[k]), *samples.position[k]])) for k in range(len(samples))
    ]
    path.write_text("\n".join(rows) + "\n")
    code, _, report = calibrate(tmp_path, path)
    out = capsys.readouterr().out
    assert code == 0
    found = json.loads(report.read_text())["discrepancy"]
    assert found["length_scale_deg"] == 5.0 and found["loglik_gain"] > 0
    assert "weighted: poses within 5 deg of each other (joints 1-3) share an error" in out
    # the residual beyond the noise is then the robot's, not the instruments'
    assert "poses within 5 deg of each other share that error" in out and "not the instruments" in out
    assert "next: accept with care: the robot errs beyond this model" in out


def test_a_set_of_table_and_white_noise_is_not_weighted(tmp_path, capsys):
    path = tmp_path / "white.csv"
    write_position_set(path, 150)
    code, _, report = calibrate(tmp_path, path)
    assert code == 0 and json.loads(report.read_text())["discrepancy"] is None
    assert "weighted:" not in capsys.readouterr().out
