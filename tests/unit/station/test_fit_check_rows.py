"""The report's ``fit_check`` judges the table a method found on every training row, whatever the
method: mcs-lmlc fitted a subset (its solver's residuals are the subset's, prior rows after them),
a baseline starts from LMLC's result (whose residuals, weights and stop it must not report)."""

import numpy as np
import pytest

from calib.consistency import chi_square_sf, noise_test
from sim_fixtures.scenario import write_scenario
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs import calibration

CAUCHY_KEEP = np.sqrt(3.0) * 3.0
"""A row stays in the test while its Cauchy weight sqrt(rho') is at least 1/2: |r| <= sqrt(3) times
the loss scale, 3 fitted noise scales (never fewer than 3 stated noises)."""


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A simulated JR680 with three gauge lines, 25 samples each."""
    sc = write_scenario(tmp_path_factory.mktemp("fitrows"), seed=3, n_lines=3, n_per_line=25)
    return load_samples(sc.samples), load_robot(sc.robot), load_setup(sc.setup)


def _recomputed(outcome, robust: bool) -> tuple[float, float]:
    """The noise ratio and p-value at the result's table on all training rows, from first principles."""
    model, cal = outcome.model, outcome.calibration
    r = model.residuals(cal.x)
    assert r.size == model.groups.size
    limit = CAUCHY_KEEP * np.maximum(cal.scale, 1.0)[model.groups]
    kept = np.abs(r) <= limit if robust else np.ones(r.size, bool)
    dof = int(kept.sum()) - int(cal.identified.sum())
    chi2 = float(np.sum(r[kept] ** 2))
    return float(np.sqrt(chi2 / dof)), chi_square_sf(chi2, dof)


def _solver_rows(outcome):
    """What the old code judged: the solver's first rows, as many as the training model has."""
    cal, m = outcome.calibration, outcome.model.groups.size
    return noise_test(cal.after.residuals[:m], cal.after.weights[:m], int(cal.identified.sum())).ratio


@pytest.mark.parametrize("method, robust", [("mcs-lmlc", True), ("gn", False)])
def test_the_fit_check_judges_the_found_table_on_every_training_row(cell, method, robust):
    out = calibration.calibrate_samples(*cell, method=method, terms="geometric")
    check = out.report.fit_check
    ratio, p = _recomputed(out, robust)
    assert check.noise_ratio == pytest.approx(ratio, rel=1e-9)
    assert check.p_value == pytest.approx(p, rel=1e-6, abs=1e-300)
    # mcs-lmlc's solver rows are a subset's with prior rows after them; a baseline's are LMLC's
    assert abs(_solver_rows(out) - ratio) > 1e-3 * ratio
    assert check.iteration_cap is False


def test_a_baseline_never_reports_lmlcs_iteration_cap(cell, monkeypatch):
    """The cap belongs to LMLC's solver; a baseline's own search has no such stop to report."""
    real = calibration.calibrate

    def capped(model, options):
        cal = real(model, options)
        cal.after.status = 0
        return cal

    monkeypatch.setattr(calibration, "calibrate", capped)
    gn = calibration.calibrate_samples(*cell, method="gn", terms="geometric").report
    lmlc = calibration.calibrate_samples(*cell, method="lmlc", terms="geometric").report
    assert lmlc.fit_check.iteration_cap and any("cap of" in w for w in lmlc.warnings)
    assert not gn.fit_check.iteration_cap and not any("cap of" in w for w in gn.warnings)
