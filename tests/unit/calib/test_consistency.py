"""The statistics a fit takes of itself: the chi-square of its whitened residual against the stated
noise, and how far each parameter moved in its prior sigmas."""

import numpy as np
from scipy.special import erfc

from calib.consistency import chi_square_sf, dial_gain, excursions, neighbour_agreement, noise_test, wild_rows


def test_chi_square_tail_matches_its_closed_forms():
    x = np.array([0.1, 1.0, 4.0, 30.0])
    assert np.allclose([chi_square_sf(v, 2) for v in x], np.exp(-x / 2))  # two degrees: exponential
    assert np.allclose([chi_square_sf(v, 1) for v in x], erfc(np.sqrt(x / 2)))  # one: a squared normal


def test_residuals_at_the_stated_noise_pass_and_three_times_it_fail():
    rng = np.random.default_rng(7)
    m, k = 3000, 30
    r, w = rng.normal(size=m), np.ones(m)
    ok = noise_test(r, w, k)
    assert ok.dof == m - k and ok.kept == ok.rows == m
    # sqrt(chi2 / dof) has a standard deviation of about 1 / sqrt(2 dof): 0.013 here
    assert abs(ok.ratio - 1.0) < 4 / np.sqrt(2 * ok.dof)
    assert ok.p_value > 1e-4
    bad = noise_test(3.0 * r, w, k)
    assert abs(bad.ratio - 3.0) < 12 / np.sqrt(2 * bad.dof) and bad.p_value < 1e-300


def test_down_weighted_rows_stay_out_of_the_test_but_not_out_of_all_rows():
    rng = np.random.default_rng(8)
    r, w = rng.normal(size=1000), np.ones(1000)
    r[:10], w[:10] = 1000.0, 0.01  # ten gross readings the robust loss cut
    test = noise_test(r, w, 20)
    assert test.kept == 990 and test.dof == 970
    assert abs(test.ratio - 1.0) < 4 / np.sqrt(2 * test.dof)
    assert test.ratio_all > 90  # sqrt(10 * 1000^2 / 980)


def test_excursions_count_prior_sigmas_of_the_fitted_unknowns_only():
    x0 = np.zeros(4)
    x = np.array([3.0, -0.5, 10.0, 7.0])
    sigma = np.array([1.0, 0.1, np.inf, 1.0])
    free = np.array([True, True, True, False])
    assert np.allclose(excursions(x, x0, sigma, free), [3.0, 5.0, 0.0, 0.0])


def test_a_row_a_hundred_median_errors_off_is_wild():
    errors = np.array([0.3, -0.2, 0.5, 99000.0, 0.4, -2.0])
    assert wild_rows(errors, 100.0).tolist() == [3]
    assert wild_rows(errors, 4.0).tolist() == [3, 5]  # the median is 0.45 mm


def test_dial_gain_recovers_the_dial_axis_and_its_sign():
    rng = np.random.default_rng(5)
    point, direction = np.array([100.0, -50.0, 300.0]), np.array([0.0, 1.0, 0.0])
    axis = np.array([0.0, 0.6, 0.8])  # partly along the line: only its part across it shows
    dial = rng.uniform(-0.3, 0.3, 40)
    along = rng.uniform(-200, 200, 40)
    noise = 0.005
    tcp = point + along[:, None] * direction + dial[:, None] * axis + rng.normal(0, noise, (40, 3))
    for sign in (1.0, -1.0):
        found = dial_gain(tcp, point, direction, sign * dial)
        np.testing.assert_allclose(found.gain, sign * np.array([0.0, 0.0, 0.8]), atol=5 * found.sigma)
        assert 0.2 * noise / np.std(dial) / np.sqrt(40) < found.sigma < 5 * noise / np.std(dial) / np.sqrt(40)


def test_neighbours_agree_on_a_smooth_error_and_not_on_noise():
    """A residual that is a function of the pose (a sag growing with joint 2's cosine) is shared by
    neighbouring poses; independent noise is not, within a few of its standard errors 1/sqrt(N k)."""
    rng = np.random.default_rng(3)
    n = 1500
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    smooth = np.column_stack([np.cos(q[:, 1]), np.sin(q[:, 2]), np.cos(q[:, 0] - q[:, 1])])
    noise = rng.normal(size=(n, 3))
    assert abs(neighbour_agreement(q, noise)) < 4 / np.sqrt(noise.size)
    assert neighbour_agreement(q, smooth + 0.3 * noise) > 0.5
    assert neighbour_agreement(q, smooth[:, 0], chunk=97) == neighbour_agreement(q, smooth[:, 0])
