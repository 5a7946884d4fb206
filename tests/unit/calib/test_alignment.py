"""calib.alignment against known truth: synthetic streams with a known clock offset and a known lag."""

import numpy as np
import pytest

from calib.alignment import (
    clock_offset,
    estimate_lag,
    interpolate,
    interpolation_error,
    pass_rates,
    steepest_rate,
)

RNG = np.random.default_rng(7)


def test_interpolation_is_exact_for_linear_motion_and_never_bridges_a_gap():
    t_known = np.array([0.0, 1.0, 2.0, 5.0, 6.0])
    values = np.column_stack([3 * t_known + 1, -t_known])
    got, ok = interpolate(t_known, values, np.array([0.5, 1.75, 3.0, 5.5, 6.5, -0.1]), max_gap_s=1.5)
    assert ok.tolist() == [True, True, False, True, False, False]
    np.testing.assert_allclose(
        got[ok], np.column_stack([3 * np.array([0.5, 1.75, 5.5]) + 1, -np.array([0.5, 1.75, 5.5])])
    )
    assert np.isnan(got[~ok]).all()


def test_clock_offset_is_the_least_transit():
    stamp = np.arange(1000) * 0.002
    transit = 0.0003 + RNG.exponential(0.001, 1000)  # never below the link's 0.3 ms
    arrival = stamp + 100.0 + transit
    assert clock_offset(stamp, arrival) == pytest.approx(100.0003, abs=2e-5)


def _sweep(lag_s: float, noise: float, passes: int = 6):
    """A length along passes: trapezoid sweeps (speed 40, accel 400 per s) with dwells, a smooth
    model error per pass, read with ``noise`` at jittered times ``lag_s`` late."""
    t_all, y_all, g_all, u_all = [], [], [], []
    truth_t, truth_s = [], []
    t0 = 0.0
    for p in range(passes):
        length, v, a = 150.0 + 20 * p, 40.0, 400.0
        ta = v / a
        dur = length / v + ta
        tt = np.linspace(0, dur + 1.0, 4000)  # 0.5 s dwell each end
        m = np.clip(tt - 0.5, 0, dur)
        s = np.where(
            m < ta,
            0.5 * a * m**2,
            np.where(m > dur - ta, length - 0.5 * a * (dur - m) ** 2, 0.5 * a * ta**2 + v * (m - ta)),
        )
        truth_t.append(t0 + tt)
        truth_s.append(s + 1000.0 * p)
        t_read = np.sort(RNG.uniform(0.1, dur + 0.9, 1500))  # within the dwells: the truth covers any lag
        s_read = np.interp(t_read - lag_s, tt, s)
        model_error = 0.3 * np.sin(s_read / 100.0 + p) + 0.001 * s_read  # smooth along the pass
        y = 800.0 - 0.7 * s_read + model_error + RNG.normal(0, noise, len(t_read))
        t_all.append(t0 + t_read)
        y_all.append(y)
        g_all.append(np.full(len(t_read), p))
        u_all.append(s_read)
        t0 += dur + 3.0
    tt, ss = np.concatenate(truth_t), np.concatenate(truth_s)
    speed = np.concatenate([np.gradient(s, t) for s, t in zip(truth_s, truth_t, strict=True)])

    def predict(at):
        return 800.0 - 0.7 * (np.interp(at, tt, ss) % 1000.0), -0.7 * np.interp(at, tt, speed)

    return predict, np.concatenate(t_all), np.concatenate(y_all), np.concatenate(g_all), np.concatenate(u_all)


@pytest.mark.parametrize("lag_s", [0.0, 0.005, -0.003])
def test_a_known_lag_is_found_within_its_stated_uncertainty(lag_s):
    noise = 0.02
    predict, t, y, g, u = _sweep(lag_s, noise)
    found = estimate_lag(predict, t, y, g, u)
    assert abs(found.lag_s - lag_s) < 4 * found.sigma_s + 1e-4
    assert found.sigma_s < 1e-3  # 9000 readings at 0.02 mm: the lag to well under a millisecond
    if lag_s:
        assert found.rms_at_lag < found.rms_as_stated


def test_a_rate_that_never_changes_says_nothing_about_a_lag():
    t = np.linspace(0, 1, 200)
    found = estimate_lag(
        lambda at: (np.zeros_like(at), np.ones_like(at)), t, np.zeros_like(t), np.zeros(200), t
    )
    assert found.lag_s == 0.0 and np.isinf(found.sigma_s)


def test_steepest_rate_is_the_steepest_slope_of_a_slow_sensors_trend():
    # a dial on the edge: a slow drift of known rate along each pass, read with 2 um noise
    rng = np.random.default_rng(3)
    t = np.concatenate([np.linspace(0, 10, 500), np.linspace(20, 25, 300)])
    groups = np.repeat([0, 1], [500, 300])
    drift = np.where(groups == 0, 0.004 * t, -0.01 * (t - 20) + 0.002 * (t - 20) ** 2)
    truth = max(0.004, 0.01)  # mm/s: the second pass's slope at its start
    rate = steepest_rate(t, drift + rng.normal(0, 0.002, len(t)), groups)
    assert truth <= rate < truth + 0.004  # the trend found, the noise's end effects small
    assert steepest_rate(t[:1], drift[:1], groups[:1]) == 0.0


def test_interpolation_error_is_a_parabolas_and_nothing_on_a_line():
    """On a parabola sampled unevenly the bound is within a factor 2 of the true midpoint error of
    the segment around each time (h^2 c / 8: the neighbours' slopes differ by c times the mean of
    the two segments, spaced here within a factor 3); on a line zero; beside a NaN reading inf."""
    t_known = np.cumsum(np.r_[0.0, np.random.default_rng(0).uniform(0.005, 0.015, 40)])
    c = 30.0  # mm/s^2
    t = (t_known[1:-2] + t_known[2:-1]) / 2  # segment midpoints, away from the ends
    bound = interpolation_error(t_known, c * t_known**2 / 2, t)
    linear, _ = interpolate(t_known, c * t_known**2 / 2, t, 1.0)
    ratio = bound / np.abs(linear[:, 0] - c * t**2 / 2)
    assert np.all((ratio >= 0.5) & (ratio <= 2.0))
    np.testing.assert_allclose(interpolation_error(t_known, 2.0 * t_known - 1.0, t), 0.0, atol=1e-12)
    with_gap = np.where(np.arange(len(t_known)) == 20, np.nan, t_known)
    assert np.isinf(interpolation_error(t_known, with_gap, t[18:20])).all()


def test_pass_rates_are_each_passs_own_time_derivative():
    t = np.r_[np.linspace(0.0, 1.0, 50), np.linspace(5.0, 6.0, 30)]
    groups = np.r_[np.zeros(50, int), np.ones(30, int)]
    values = np.where(groups == 0, 3.0 * t, -2.0 * t**2)
    order = np.random.default_rng(1).permutation(len(t))  # rows need not come in time order
    rate = pass_rates(values[order], t[order], groups[order])
    expected = np.where(groups == 0, 3.0, -4.0 * t)[order]
    inner = (t[order] > 5.0) & (t[order] < 6.0) | (groups[order] == 0)
    np.testing.assert_allclose(rate[inner], expected[inner], rtol=1e-2)
    assert np.all(pass_rates(values, t, np.full(len(t), -1)) == 0.0)  # no pass: no rate
