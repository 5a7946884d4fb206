"""The station's own check that a calibration carries over: where the calibrated model predicts the
left-out regions of joint space worse than the nominal table on the same folds, the report warns
(a robot already as its table says, measured in a corner by a noisy instrument); where the table
has errors to correct, it does not."""

import numpy as np
import pytest

import configs
from calib import calibrate as calibrate_module
from calib.calibrate import WithPrior
from calib.kinematics import tcp_position
from calib.models import spread_rows
from calib.params import dh_from_degrees
from station.formats.samples import Samples, load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs.calibration import build_model, calibrate_samples
from station.jobs.terms import _drawn

ROBOT = load_robot(configs.path("robots/ur10.toml"))


def tracker_set(machining: float, noise_mm: float, spread_deg: float, n: int, seed: int = 3) -> Samples:
    """A UR10 whose table is off by ``machining`` (deg and 5x mm, 1 sigma), ``n`` poses within
    ``spread_deg`` of one configuration, a tracker reading with ``noise_mm`` per axis."""
    rng = np.random.default_rng(seed)
    nominal = dh_from_degrees(ROBOT.table_deg())
    true = nominal + np.column_stack(
        [
            np.radians(rng.normal(0, machining, 6)),
            rng.normal(0, 5 * machining, (6, 2)),
            np.radians(rng.normal(0, machining, 6)),
        ]
    )
    q = np.array([0.0, -60.0, 80.0, -100.0, -90.0, 0.0]) + rng.uniform(-spread_deg, spread_deg, (n, 6))
    p = tcp_position(true, np.radians(q), np.array(ROBOT.tool_mm)) + rng.normal(0, noise_mm, (n, 3))
    return Samples("tracker.csv", "position", q, p, np.full(n, np.nan), np.full(n, -1))


@pytest.mark.parametrize("terms", ["geometric", "auto"])
def test_a_table_worse_than_nominal_away_from_its_poses_is_named(terms):
    report = calibrate_samples(tracker_set(0.0, 0.3, 25.0, 60), ROBOT, None, terms=terms).report
    (warning,) = [w for w in report.warnings if "worse than the nominal table" in w]
    assert "regions of joint space" in warning and "do not use this table" in warning


def test_no_warning_where_the_table_had_errors_to_correct():
    report = calibrate_samples(tracker_set(0.15, 0.02, 90.0, 150), ROBOT, None, terms="geometric").report
    assert not [w for w in report.warnings if "worse than the nominal table" in w]


@pytest.mark.parametrize("kind", ["position", "drawstring"])
def test_the_check_on_a_draw_keeps_each_rows_weight_and_flag(kind, three_lines, monkeypatch):
    """Above ``COARSE_ROWS`` rows the check scores the robust fits' draw: each of the drawn model's
    residual rows carries the weight its row had in the whole model's (the residuals of a row in
    the draw, in the drawn model's order), each sample row its kept flag."""
    if kind == "position":
        model = build_model(tracker_set(0.15, 0.02, 90.0, 150), ROBOT, None, "")
    else:
        files = [three_lines.samples, three_lines.robot, three_lines.setup]
        model = build_model(load_samples(files[0]), load_robot(files[1]), load_setup(files[2]), "")
    monkeypatch.setattr(calibrate_module, "COARSE_ROWS", 60)
    prior = WithPrior(model, model.x0)
    key = prior.rows * 10.0 + prior.groups  # a weight that names its residual's row and group
    kept = np.arange(len(model.samples)) % 3 > 0
    drawn, weights, flags = _drawn(model, key, kept)
    drawn_prior = WithPrior(drawn, drawn.x0)
    pick = spread_rows(len(model.samples), 60)
    assert len(drawn.samples) == 60 and np.array_equal(flags, kept[pick])
    rows = np.where(drawn_prior.rows >= 0, pick[drawn_prior.rows], -1)
    np.testing.assert_array_equal(weights, rows * 10.0 + drawn_prior.groups)
