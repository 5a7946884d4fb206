"""Time alignment of streamed readings (sweep sessions): one time base, joints interpolated at the
sensors' readings, and each sensor's latency estimated from the readings themselves.

Terms: a *stream* is a device's readings with the times they were taken on the station's clock
[s]; the robot's packages carry the controller's timestamps, mapped onto the station's clock by the
*clock offset* (the least transit seen: a package read the instant it arrived shows the offset
plus the link's least latency, the floor every other package sits above). A sensor's *latency*
[s] is how long before its timestamp the value it reports was true: the reading stamped ``t``
measures the world at ``t - latency``.

The latency estimate (:func:`estimate_lag`): the *misfit* of a sensor against what the joints
predict for it (e.g. the drawstring's length from the nominal kinematics) holds the model's error,
smooth along each pass of the sweep, plus ``-rate * lag``: a sensor later than stated by ``lag``
reads what the prediction held ``lag`` earlier. Per pass a polynomial in the position along the
pass takes the smooth part; the lag is what remains, fitted by linear least squares and refined
(the prediction re-taken at the new lag; a step that raises the misfit halved) until it moves less
than a microsecond. Its information
comes where the sensor's rate changes along the pass: the robot's accelerations and stops at the
passes' ends. A sensor that barely changes along a pass (a dial on the edge reads only the tool's
error across it) carries no information on its latency, and a latency error barely moves its rows:
:func:`steepest_rate` says about how much.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POLY_DEGREE = 5  # the smooth model error along one pass: a quintic in the position along it
HALVINGS = 8  # a lag step that raises the misfit is halved this often before the search stops
MIN_RATE_SPREAD = 1e-9  # a rate this flat over every pass carries no information about a lag


def clock_offset(stamp_s, arrival_s) -> float:
    """The station's clock minus the controller's [s], from packages' controller timestamps and
    their arrival times on the station's clock (the least transit: module notes)."""
    return float(np.min(np.asarray(arrival_s, float) - np.asarray(stamp_s, float)))


def interpolate(t_known, values, t, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``values`` (N, D) known at increasing times ``t_known`` (N,) [s], linearly interpolated at
    times ``t`` (M,); and a mask (M,) of the times that lie between two known ones no farther apart
    than ``max_gap_s`` (elsewhere the value is NaN: never extrapolated or bridged over a gap)."""
    t_known, t = np.asarray(t_known, float), np.asarray(t, float)
    values = np.asarray(values, float).reshape(len(t_known), -1)
    out = np.full((len(t), values.shape[1]), np.nan)
    if len(t_known) < 2:
        return out, np.zeros(len(t), bool)
    right = np.clip(np.searchsorted(t_known, t, side="right"), 1, len(t_known) - 1)
    left = right - 1
    gap = t_known[right] - t_known[left]
    ok = (t >= t_known[0]) & (t <= t_known[-1]) & (gap <= max_gap_s) & (gap > 0)
    w = np.where(ok, (t - t_known[left]) / np.where(gap > 0, gap, 1.0), 0.0)[:, None]
    out[ok] = ((1 - w) * values[left] + w * values[right])[ok]
    return out, ok


@dataclass(frozen=True)
class Lag:
    """A sensor's latency beyond the stated one [s] (positive: later than stated), its standard
    error [s] from the misfit's scatter, the misfit's RMS at that lag and at the stated latency
    [the sensor's unit], and the readings used."""

    lag_s: float
    sigma_s: float
    rms_at_lag: float
    rms_as_stated: float
    n: int


def estimate_lag(predict, t, measured, groups, position, *, iterations: int = 5) -> Lag:
    """The lag [s] of a sensor's readings ``measured`` (N,) taken at times ``t`` (N,) [s, already
    moved back by the stated latency] against ``predict(times) -> (values (N,), rates (N,) per s)``,
    the joints' prediction for them; ``groups`` (N,) the pass of each reading and ``position`` (N,)
    where along its pass (any smooth coordinate, e.g. mm along the line). See the module notes."""
    t, measured = np.asarray(t, float), np.asarray(measured, float)
    groups, position = np.asarray(groups), np.asarray(position, float)
    design = _pass_polynomials(groups, position)
    lag, sigma = 0.0, np.inf
    predicted, rate = predict(t)
    first_rms = rms = _smooth_rms(design, measured - predicted)
    if np.ptp(rate) < MIN_RATE_SPREAD:
        return Lag(0.0, np.inf, first_rms, first_rms, len(t))
    for _ in range(iterations):
        step, sigma = _lag_step(design, -rate, measured - predicted)
        for _ in range(HALVINGS):  # a step that does not lower the misfit is halved
            trial, trial_rate = predict(t - lag - step)
            trial_rms = _smooth_rms(design, measured - trial)
            if trial_rms <= rms:
                break
            step /= 2
        else:
            break
        lag, predicted, rate, rms = lag + step, trial, trial_rate, trial_rms
        if abs(step) < 1e-6:
            break
    return Lag(lag, sigma, rms, first_rms, len(t))


def steepest_rate(t, values, groups, degree: int = 3) -> float:
    """The largest rate of change [unit per s] of a sensor's smooth part along its passes: per pass
    (``groups`` (N,)) a polynomial of ``degree`` in time fitted to ``values`` (N,) at ``t`` (N,)
    [s], its derivative's largest magnitude at the readings (0 without a pass of two readings).
    A latency off by ``dt`` moves the sensor's aligned rows by about this times ``dt`` where its
    trend is steepest (the trend's, not the readings': no bound on a faster change between them)."""
    t, values, groups = np.asarray(t, float), np.asarray(values, float), np.asarray(groups)
    steepest = 0.0
    for g in np.unique(groups):
        on = (groups == g) & np.isfinite(values)
        if on.sum() < 2 or np.ptp(t[on]) <= 0:
            continue
        fit = np.polynomial.Polynomial.fit(t[on], values[on], min(degree, on.sum() - 1))
        steepest = max(steepest, float(np.max(np.abs(fit.deriv()(t[on])))))
    return steepest


def _pass_polynomials(groups, position) -> np.ndarray:
    """Design matrix (N, passes * (degree + 1)): per pass, powers of its position scaled to [-1, 1]."""
    ids = np.unique(groups)
    columns = []
    for g in ids:
        on = groups == g
        u = position[on]
        mid, half = (u.max() + u.min()) / 2, max((u.max() - u.min()) / 2, 1e-12)
        scaled = np.zeros(len(groups))
        scaled[on] = (u - mid) / half
        degree = min(POLY_DEGREE, max(on.sum() - 1, 0))
        columns += [np.where(on, scaled**k, 0.0) for k in range(degree + 1)]
    return np.stack(columns, axis=1)


def _smooth_rms(design, misfit) -> float:
    """RMS of ``misfit`` after the per-pass polynomials took their part."""
    coef, *_ = np.linalg.lstsq(design, misfit, rcond=None)
    return float(np.sqrt(np.mean((misfit - design @ coef) ** 2)))


def _lag_step(design, column, misfit) -> tuple[float, float]:
    """The lag's least-squares coefficient beside the per-pass polynomials, and its standard error."""
    a = np.column_stack([column, design])
    coef, *_ = np.linalg.lstsq(a, misfit, rcond=None)
    resid = misfit - a @ coef
    dof = max(len(misfit) - a.shape[1], 1)
    # the lag's variance: the residual variance over the part of the rate the polynomials leave
    p_coef, *_ = np.linalg.lstsq(design, column, rcond=None)
    left = column - design @ p_coef
    sigma = float(np.sqrt(resid @ resid / dof / max(left @ left, 1e-300)))
    return float(coef[0]), sigma


def pass_rates(values, t, groups, path=None, max_step: float = np.inf) -> np.ndarray:
    """The rate of change [unit per s] (N,) of ``values`` (N,) read at times ``t`` (N,) [s] along
    each pass (``groups`` (N,), -1: no pass), by central differences in time order. 0 on rows of
    no pass, of a pass with fewer than two distinct times, where two readings share a time, and
    where ``path`` (N, D) (e.g. the joints) moved more than ``max_step`` (any coordinate) to a
    neighbouring row: a difference quotient is a rate only over a short stretch of one path."""
    values, t, groups = np.asarray(values, float), np.asarray(t, float), np.asarray(groups)
    path = np.zeros((len(values), 1)) if path is None else np.asarray(path, float).reshape(len(values), -1)
    rate = np.zeros(len(values))
    for g in np.unique(groups[groups >= 0]):
        rows = np.flatnonzero(groups == g)
        rows = rows[np.argsort(t[rows], kind="stable")]
        if len(rows) < 2 or np.any(np.diff(t[rows]) <= 0):
            continue
        step = np.max(np.abs(np.diff(path[rows], axis=0)), axis=1)
        short = np.r_[step[0], np.maximum(step[:-1], step[1:]), step[-1]] <= max_step
        rate[rows] = np.where(short, np.gradient(values[rows], t[rows]), 0.0)
    return rate


def interpolation_error(t_known, values, t) -> np.ndarray:
    """About how far (N,) [the values' unit] linear interpolation of ``values`` (K,) known at
    increasing times ``t_known`` (K,) [s] may be off at times ``t`` (N,): ``h / 8`` times the change
    of slope from the segment around each time to its neighbours (``h`` the segment's length; a
    parabola's interpolation error, exactly). Inf where a neighbour is NaN (a reading beside a
    gap: the value changed in a way the readings do not show); 0 with fewer than three readings."""
    t_known, values, t = np.asarray(t_known, float), np.asarray(values, float), np.asarray(t, float)
    if len(t_known) < 3:
        return np.zeros(len(t))
    h = np.diff(t_known)
    slope = np.diff(values) / np.where(h > 0, h, np.nan)
    k = np.clip(np.searchsorted(t_known, t, side="right") - 1, 0, len(h) - 1)
    before = np.abs(slope[k] - slope[np.maximum(k - 1, 0)])
    after = np.abs(slope[np.minimum(k + 1, len(h) - 1)] - slope[k])
    return np.nan_to_num(np.maximum(before, after), nan=np.inf) * h[k] / 8
