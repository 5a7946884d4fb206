import numpy as np
import pytest

from calib.calibrate import fit_setup
from calib.kinematics import N_DH
from calib.metrics import error_metrics
from calib.observability import anneal, configuration_information, indices, singular_values
from errors import ParameterError
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs import calibration


@pytest.fixture(scope="module")
def problem(one_line):
    model = calibration.build_model(
        load_samples(one_line.samples), load_robot(one_line.robot), load_setup(one_line.setup), "setup"
    )
    prep = fit_setup(model)
    _, jac = model.residuals_and_jacobian(prep.before.x)
    return model, jac[:, prep.free], np.flatnonzero(prep.free) < N_DH


def test_schur_singular_values_match_projected_svd(problem, rng):
    model, jac, table = problem
    n0 = len(model.samples)
    info = configuration_information(jac, model.rows, n0, table)
    subset = rng.choice(n0, 60, replace=False)
    keep = np.isin(model.rows, subset)
    scaled = jac[keep] / np.linalg.norm(jac, axis=0)
    t, s = scaled[:, table], scaled[:, ~table]
    projected = t - s @ np.linalg.lstsq(s, t, rcond=None)[0]
    expected = np.linalg.svd(projected, compute_uv=False)
    np.testing.assert_allclose(singular_values(info[subset].sum(0), int(table.sum())), expected, rtol=1e-6)


def test_indices_definitions():
    sv = np.array([4.0, 2.0, 1.0])
    o = indices(sv, 4)
    assert o["O1"] == pytest.approx(2.0 / 2.0)
    assert (o["O2"], o["O3"], o["O4"]) == (0.25, 1.0, 0.25)
    assert o["O5"] == pytest.approx(1 / 1.75)


def test_annealing_beats_random_subsets_and_keeps_every_line(problem, rng):
    model, jac, table = problem
    n0 = len(model.samples)
    info = configuration_information(jac, model.rows, n0, table)
    groups = np.arange(n0) % 3  # pretend three lines to exercise the per-line minimum
    sel = anneal(info, int(table.sum()), 40, groups, np.random.default_rng(1), iterations=1500)
    random_best = max(
        indices(singular_values(info[rng.choice(n0, 40, replace=False)].sum(0), int(table.sum())), 40)["O1"]
        for _ in range(50)
    )
    assert sel.value > random_best
    assert sel.rows.size == 40 and np.unique(sel.rows).size == 40
    assert min(np.sum(groups[sel.rows] == g) for g in range(3)) >= 4


def test_mcs_lmlc_selects_and_stays_at_the_noise_floor(one_line):
    args = load_samples(one_line.samples), load_robot(one_line.robot), load_setup(one_line.setup)
    holdout = load_samples(one_line.holdout)
    out = calibration.calibrate_samples(*args, holdout=holdout, method="mcs-lmlc", select=72)
    assert len(out.report.selection.rows) == 72
    # the training metrics cover all 200 rows, not only the 72 selected
    every_row = error_metrics(out.model.row_error_mm(out.calibration.x))
    assert len(out.model.samples) == 200 and out.report.after.train.rmse_mm == every_row["rmse_mm"]
    lmlc = calibration.calibrate_samples(*args, holdout=holdout)
    assert out.report.after.holdout.rmse_mm < 1.5 * lmlc.report.after.holdout.rmse_mm


def test_select_out_of_range_is_bad_input_naming_the_parameter(one_line):
    args = load_samples(one_line.samples), load_robot(one_line.robot), load_setup(one_line.setup)
    with pytest.raises(ParameterError, match="^select 5: must lie between the 2[0-9] unknowns and the 200"):
        calibration.calibrate_samples(*args, method="mcs-lmlc", select=5)
    with pytest.raises(ParameterError, match="^select 72: selecting configurations needs method mcs-lmlc"):
        calibration.calibrate_samples(*args, select=72)
