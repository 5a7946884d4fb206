"""``station.jobs.absorbed`` on simulated cells: down-weighted rows as a finding with their cause,
each line's dial judged against its rows, and the nominal table's expected error."""

import dataclasses

import numpy as np

from calib.calibrate import CalibrationOptions, robust_weights
from sim_fixtures.scenario import write_scenario
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs import absorbed, calibration


def _outcome(scenario, setup=None):
    return calibration.calibrate_samples(
        load_samples(scenario.samples), load_robot(scenario.robot), setup or load_setup(scenario.setup)
    )


def test_a_clean_cell_has_no_finding_and_every_dial_agrees(three_lines):
    outcome = _outcome(three_lines)
    check = outcome.report.fit_check
    assert [d.verdict for d in check.dial_lines] == ["agrees"] * 3
    for d in check.dial_lines:  # the gain is the stated axis across the line, to its standard error
        assert d.sigma < 0.05
    assert not [w for w in outcome.report.warnings if "down-weighted" in w]
    assert check.dial_mode is None and check.nominal_rmse_mm > 10 * outcome.report.workspace.predicted_rmse_mm


def test_many_gross_drawstring_readings_are_a_finding_naming_the_drawstring(tmp_path):
    scenario = write_scenario(tmp_path, seed=3, n_lines=3, n_per_line=50, outlier_fraction=0.12)
    report = _outcome(scenario).report
    found = [w for w in report.warnings if "down-weighted" in w]
    assert len(report.downweighted) > 0.05 * 150
    assert found and "by their drawstring readings" in found[0], report.warnings
    assert report.fit_check.verdict != "consistent"


def test_most_rows_of_one_line_down_weighted_name_that_line(three_lines):
    outcome = _outcome(three_lines)
    model, cal = outcome.model, outcome.calibration
    weights = robust_weights(model.residuals(cal.x), model.groups, cal.scale, CalibrationOptions())
    line0 = np.flatnonzero(model.placement_ids() == 0)[:30]  # 30 of its 50 rows
    weights[np.isin(model.rows, line0) & (model.groups != 0)] = 0.1
    cut = dataclasses.replace(cal, downweighted=line0)
    (message,) = absorbed.downweighted(model, cut, weights)
    assert message.startswith("most rows of line 0 (30 of 50) are down-weighted by their line contact")


def test_a_dial_read_on_another_axis_is_named_with_its_direction(three_lines):
    setup = load_setup(three_lines.setup)
    axis = np.array(setup.lines[1].dial_axis)
    other = np.cross(axis, [0.3, 0.5, 0.8])
    lines = [ln.model_copy(update={"dial_axis": other.tolist()}) if ln.id == 1 else ln for ln in setup.lines]
    check = _outcome(three_lines, setup.model_copy(update={"lines": lines})).report.fit_check
    verdicts = {d.line: d for d in check.dial_lines}
    assert verdicts[1].verdict == "other axis"
    assert "line 1's dial readings move the tool along" in check.refusal
    gain = np.array(verdicts[1].gain)
    assert abs(gain @ axis) / np.linalg.norm(gain) > 0.95  # the gain points along the true axis


def test_dial_readings_that_do_not_follow_the_tool_are_refused(three_lines, tmp_path):
    # line 2's readings shuffled among its rows: the dial reads, but not this tool on this edge
    samples = load_samples(three_lines.samples)
    rows = np.flatnonzero(samples.line == 2)
    dial = samples.dial_mm.copy()
    dial[rows] = np.random.default_rng(0).permutation(dial[rows])
    shuffled = dataclasses.replace(samples, dial_mm=dial)
    outcome = calibration.calibrate_samples(
        shuffled, load_robot(three_lines.robot), load_setup(three_lines.setup)
    )
    check = outcome.report.fit_check
    assert [d.verdict for d in check.dial_lines] == ["agrees", "agrees", "does not follow"]
    assert "line 2's dial readings do not follow the tool's distance from the edge" in check.refusal
