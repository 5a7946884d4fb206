"""The drift test and the likely changes against a known truth: a linear model whose rows are unit
noise, the table's own error drawn from its covariance, and (for a drift) one parameter changed."""

import numpy as np

from calib.verification import caught_changes, drift_test, likely_changes, sensitive_rows

M, S, K = 120, 4, 6


def _model(rng):
    return rng.normal(size=(M, S)), rng.normal(size=(M, K)) * 0.5


def test_an_unchanged_robot_passes_at_the_stated_rate_with_the_tables_uncertainty_counted(rng):
    jac_s, jac_r = _model(rng)
    cov = np.diag(rng.uniform(0.5, 2.0, K))  # the table's own error: as large as the noise
    p, p_ignored = [], []
    for _ in range(400):
        d = rng.multivariate_normal(np.zeros(K), cov)
        r = rng.normal(size=M) - jac_r @ d + jac_s @ rng.normal(size=S)
        r -= jac_s @ np.linalg.lstsq(jac_s, r, rcond=None)[0]  # the setup fit
        args = (r, np.ones(M), np.ones(M), jac_s, jac_r)
        p.append(drift_test(*args, cov).p_value)
        p_ignored.append(drift_test(*args, None).p_value)
    # with the table's covariance the p-values are about uniform: 5 % below 0.05 (binomial 3 sigma
    # of 400 draws: +-3.3 %); without it, the table's error reads as drift
    assert abs(np.mean(np.array(p) < 0.05) - 0.05) < 0.033
    assert np.mean(np.array(p_ignored) < 0.05) > 0.3


def test_a_changed_parameter_is_named_first_with_its_change_and_sigma(rng):
    jac_s, jac_r = _model(rng)
    delta = np.zeros(K)
    delta[3] = 2.0
    hits = 0
    for _ in range(50):
        r = rng.normal(size=M) - jac_r @ delta  # residual = model - measurement
        r -= jac_s @ np.linalg.lstsq(jac_s, r, rcond=None)[0]
        changes = likely_changes(r, np.ones(M), np.ones(M), jac_s, jac_r, np.arange(K), jac_r, None)
        best = changes[0]
        assert best.index == 3
        hits += abs(best.change - 2.0) < 3 * best.sigma
        assert drift_test(r, np.ones(M), np.ones(M), jac_s, jac_r, None).p_value < 1e-3
    assert hits >= 47  # 3 sigma: 99.7 %


def test_a_down_weighted_row_stays_out_of_the_test(rng):
    jac_s, jac_r = _model(rng)
    r = rng.normal(size=M)
    r -= jac_s @ np.linalg.lstsq(jac_s, r, rcond=None)[0]
    clean = drift_test(r, np.ones(M), np.ones(M), jac_s, jac_r, None)
    r[7], weights = 500.0, np.ones(M)
    weights[7] = 0.01
    assert drift_test(r, weights, np.ones(M), jac_s, jac_r, None).dof == clean.dof - 1


def test_the_sensitive_rows_see_the_parameters_better_than_random_ones(rng):
    jac_s = rng.normal(size=(3 * 40, S))
    jac_r = rng.normal(size=(3 * 40, K)) * np.repeat(rng.uniform(0.1, 2.0, 40), 3)[:, None]
    rows = np.repeat(np.arange(40), 3)
    chosen, logdet = sensitive_rows(jac_s, jac_r, rows, np.full(K, 10.0), 10)
    assert len(set(chosen.tolist())) == 10
    for _ in range(20):
        other = rng.choice(40, 10, replace=False)
        keep = np.isin(rows, other)
        _, random_logdet = sensitive_rows(jac_s[keep], jac_r[keep], rows[keep], np.full(K, 10.0), 10)
        assert logdet > random_logdet


def test_the_smallest_caught_change_is_caught_nine_times_in_ten(rng):
    """A change of the size ``caught_changes`` names clears the single-parameter test (z >= 3) in
    about 90 % of draws (binomial 3 sigma of 400: +-4.5 %); half of it in far fewer. The table's
    own error is drawn from its sigma, as a real table's is."""
    jac_s, jac_r = _model(rng)
    table_sigma = np.full(K, 0.05)
    z_test, k = 3.0, 2
    table_cov = np.diag(table_sigma**2)
    caught = caught_changes(np.ones(M), np.ones(M), jac_s, jac_r, jac_r, table_cov, z_test + 1.2816)
    assert np.all(np.isfinite(caught)) and np.all(caught > 0)
    rates = []
    for size in (caught[k], caught[k] / 2):
        hits = 0
        for _ in range(400):
            delta = rng.normal(0, table_sigma)
            delta[k] += size
            r = rng.normal(size=M) - jac_r @ delta
            r -= jac_s @ np.linalg.lstsq(jac_s, r, rcond=None)[0]
            found = likely_changes(r, np.ones(M), np.ones(M), jac_s, jac_r, np.arange(K), jac_r, table_cov)
            hits += next(c for c in found if c.index == k).z >= z_test
        rates.append(hits / 400)
    assert abs(rates[0] - 0.9) < 0.045 and rates[1] < 0.5


def test_a_parameter_the_rows_do_not_see_is_never_caught():
    jac_s = np.eye(M, S)
    jac_r = np.zeros((M, 2))
    jac_r[:, 0] = 1.0
    jac_r[:S, 1] = 1.0  # entirely within the setup's columns: the setup fit takes it up
    caught = caught_changes(np.ones(M), np.ones(M), jac_s, jac_r, jac_r, None, 4.0)
    assert np.isfinite(caught[0]) and caught[1] == np.inf


def test_a_parameter_known_only_with_another_is_judged_by_what_the_rows_see_of_the_table(rng):
    """Two parameters that move these rows alike (a J5 zero and J5's offset on a line whose tool
    barely turns): the table knows their sum to 0.01 and each alone only to 1. Their change
    estimates scatter by the sum's uncertainty, not by each one's own sigma: the sigma said is the
    scatter seen (within 10 %), mostly the rows' noise, and far under each one's own sigma (which
    the old hypot with the own sigma gave)."""
    jac_s = rng.normal(size=(M, S))
    col = rng.normal(size=M)
    jac_r = np.column_stack([col, col])
    along, across = np.array([1.0, 1.0]) / np.sqrt(2), np.array([1.0, -1.0]) / np.sqrt(2)
    table_cov = 0.01**2 / 2 * np.outer(along, along) + 1.0**2 * np.outer(across, across)
    changes, said = [], None
    for _ in range(400):
        d = rng.multivariate_normal(np.zeros(2), table_cov)
        r = rng.normal(size=M) - jac_r @ d
        r -= jac_s @ np.linalg.lstsq(jac_s, r, rcond=None)[0]
        found = likely_changes(r, np.ones(M), np.ones(M), jac_s, jac_r, np.arange(2), jac_r, table_cov)
        first = next(c for c in found if c.index == 0)
        changes.append(first.change)
        said = first.sigma
    seen = float(np.std(changes))
    assert abs(said / seen - 1.0) < 0.1
    assert said < np.sqrt(table_cov[0, 0]) / 5
