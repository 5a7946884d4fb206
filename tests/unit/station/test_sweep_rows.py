"""A sweep pass's rows from synthetic streams (``station.acquire.sweep``): joints interpolated at
each reading's time less the stated latency, and the rows the calibration must never use (too
fast, dial off the edge, no dial reading, no robot data, timing uncertain) kept apart with their
reason."""

import numpy as np
import pytest

import configs
from station.acquire.stream import SensorStream
from station.acquire.sweep import Kinematics, SweepRules, SweepSession, _Run
from station.formats.plan import Plan
from station.formats.tables import load_robot, load_setup

A = np.array([0.0, -60.0, -30.0, 0.0, -90.0, 0.0])
B = A + np.array([20.0, 5.0, 0.0, 0.0, 0.0, 0.0])
RULES = dict(
    time_scale=1.0,
    latency_s={"drawstring": 0.004, "dial": 0.0},
    max_gap_s=0.05,
    row_spacing_s=0.0,
    tolerance_s=0.002,
    timing_limit_mm=0.01,  # mm: half the drawstring's 0.02 mm noise
    dial_limit_mm=0.01,  # mm: the line noise
    dial_range_mm=(-2.0, 2.0),
    length_range_mm=(50.0, 5000.0),
    match_deg=2.0,
    target_timeout_s=60.0,
    unreachable_s=30.0,
)


class _Folder:
    header = {"start_wall_s": 0.0}
    next_sample = 0
    rows: list = []


def _path(t):
    """The robot's joints [deg] and their speeds [deg/s] at times ``t`` [s] (:class:`_Streams`)."""
    s = np.where(t < 1.0, 0.25 * t, 0.25 + 0.75 * (t - 1.0))
    rate = np.where(t < 1.0, 0.25, 0.75)
    return A + s[:, None] * (B - A), rate[:, None] * (B - A)


class _Streams:
    """The robot moving A -> B over [0, 2] s, slowly then (from 1 s) three times as fast; the
    drawstring read every 10 ms with round trips ``trip`` [s] (cycled)."""

    def __init__(self, t_dial, dial, trip=(1e-5,)):
        self.t = np.arange(0.0, 2.0005, 0.002)
        q, qd = _path(self.t)
        self.robot_arrays = {
            "stamp": self.t,
            "arrival": self.t,
            "q_deg": q,
            "qd_deg_s": qd,
            "mode": np.full(len(self.t), 7),
        }
        t_ds = np.arange(0.01, 1.99, 0.01)
        trips = list(np.resize(trip, len(t_ds)))
        self.sensors = {
            "drawstring": SensorStream("drawstring", "length_mm", list(t_ds), [900.0] * len(t_ds), trips),
            "dial": SensorStream("dial", "dial_mm", list(t_dial), list(dial), [0.001] * len(t_dial)),
        }


def _session(streams, max_speed):
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    setup = load_setup(configs.path("setups/sim.toml"))
    plan = Plan(np.arange(2), np.zeros(2, int), np.array([A, B]), sweep_pass=np.zeros(2, int))
    rules = SweepRules(max_speed_mm_s=max_speed, **RULES)
    session = SweepSession(_Folder(), plan, streams, rules, Kinematics(robot, setup))
    session.offset = 0.0  # the stamps are the station's clock already
    session._wall_minus_mono = 0.0  # and t_s the same times
    return session


def test_rows_too_fast_or_off_the_edge_are_flagged_never_stored():
    t_dial = np.arange(0.0, 2.0, 0.005)
    dial = np.where((t_dial > 0.4) & (t_dial < 0.6), np.nan, 0.1)  # lifted off
    dial[(t_dial > 1.2) & (t_dial < 1.3)] = 3.0  # outside its gate
    streams = _Streams(t_dial, dial)
    session = _session(streams, max_speed=1.0)
    speed = session.kin.speed(np.array([A, A]), np.array([0.25 * (B - A), 0.75 * (B - A)]))
    session.rules = SweepRules(max_speed_mm_s=float(speed.mean()), **RULES)
    rows, flagged, _ = session._rows(_Run(0, 0.0, 2.0, 0.0, 1.0), streams.robot_arrays)
    reason = {float(f["t_s"]): f["reason"] for f in flagged}
    t_rows = np.array([r["t_s"] for r in rows])
    assert len(rows) + len(flagged) == len(streams.sensors["drawstring"].t)
    assert np.all(t_rows < 1.0)  # from 1 s on the robot is too fast: nothing stored
    assert all(why == "too fast" for t, why in reason.items() if t > 1.01)
    assert {why for t, why in reason.items() if 0.41 < t < 0.59} == {"dial off the edge"}
    assert not np.any((t_rows > 0.4) & (t_rows < 0.6))
    # the joints of a stored row are the robot's at the reading's time less the stated latency
    r = rows[len(rows) // 2]
    q = np.array([r[f"q{i}_deg"] for i in range(1, 7)])
    np.testing.assert_allclose(q, A + 0.25 * r["t_s"] * (B - A), atol=1e-9)


def test_a_gap_in_the_dial_or_the_robot_stream_is_no_row():
    t_dial = np.r_[np.arange(0.0, 0.5, 0.005), np.arange(0.7, 2.0, 0.005)]  # no dial 0.5 .. 0.7 s
    streams = _Streams(t_dial, np.full(len(t_dial), 0.1))
    keep = (streams.t < 1.2) | (streams.t > 1.4)  # no robot package 1.2 .. 1.4 s
    streams.robot_arrays = {k: v[keep] for k, v in streams.robot_arrays.items()}
    session = _session(streams, max_speed=1e5)
    rows, flagged, _ = session._rows(_Run(0, 0.0, 2.0, 0.0, 1.0), streams.robot_arrays)
    t_rows = np.array([r["t_s"] for r in rows])
    assert not np.any((t_rows > 0.5) & (t_rows < 0.7)) and not np.any((t_rows > 1.2) & (t_rows < 1.4))
    reasons = {f["reason"] for f in flagged}
    assert reasons == {"no dial reading", "no robot data"}


@pytest.mark.parametrize("spacing", [0.05])
def test_rows_are_decimated_to_the_configured_rate(spacing):
    """One row per ``spacing``: of the five readings in each 50 ms, the best timed (the shortest
    round trip, here the middle one), not the first."""
    t_dial = np.arange(0.0, 2.0, 0.005)
    trips = (4e-3, 1e-3, 1e-4, 2e-4, 3e-3)
    streams = _Streams(t_dial, np.full(len(t_dial), 0.1), trip=trips)
    session = _session(streams, max_speed=1e5)
    session.rules = SweepRules(max_speed_mm_s=1e5, **{**RULES, "row_spacing_s": spacing})
    rows, flagged, _ = session._rows(_Run(0, 0.0, 2.0, 0.0, 1.0), streams.robot_arrays)
    assert 39 <= len(rows) + len(flagged) <= 40  # one reading of each 50 ms, of 1.97 s
    assert len(rows) >= 15 and {r["window_s"] for r in rows} == {1e-4}  # from 1 s on: too uncertain
    steps = np.diff([r["t_s"] for r in rows]) / spacing
    assert np.allclose(steps, np.round(steps)) and np.all(steps >= 1 - 1e-9)  # the same place in each slot


def test_a_reading_whose_timing_leaves_its_length_uncertain_is_flagged():
    """Against the true path: a row is flagged ``timing uncertain`` where the true length moves by
    more than the limit (half the drawstring's noise) within half the reading's round trip, or lies
    that far from the length of the joints interpolated over a gap in the robot's packages (two
    packages around the speed change at 1 s); rows far within the limit are stored."""
    t_dial = np.arange(0.0, 2.0, 0.005)
    streams = _Streams(t_dial, np.full(len(t_dial), 0.1), trip=(1e-4, 2e-4, 1e-3, 4e-3))
    keep = (streams.t < 0.981) | (streams.t > 1.019)  # packages 0.98 and 1.02 s around the change
    gap = (streams.t > 0.5) & (streams.t < 0.54)  # at constant speed: interpolation is exact
    streams.robot_arrays = {k: v[keep & ~gap] for k, v in streams.robot_arrays.items()}
    session = _session(streams, max_speed=1e5)
    rows, flagged, _ = session._rows(_Run(0, 0.0, 2.0, 0.0, 1.0), streams.robot_arrays)
    every = rows + [f for f in flagged if f["reason"] == "timing uncertain"]
    assert {f["reason"] for f in flagged} <= {"timing uncertain"}
    t = np.array([r["t_s"] for r in every])
    trip = np.resize((1e-4, 2e-4, 1e-3, 4e-3), len(streams.sensors["drawstring"].t))
    trip = trip[np.searchsorted(streams.sensors["drawstring"].t, t + 0.004 - 1e-9)]
    q_row = np.array([[r[f"q{i}_deg"] for i in range(1, 7)] for r in every])
    length = session.kin.length
    true_off = np.abs(length(_path(t + trip / 2)[0]) - length(_path(t)[0])) + np.abs(
        length(_path(t)[0]) - length(q_row)
    )
    is_flagged = np.arange(len(every)) >= len(rows)
    limit = RULES["timing_limit_mm"]
    assert np.all(is_flagged[true_off > 1.5 * limit]) and np.all(~is_flagged[true_off < 0.5 * limit])
    assert np.sum(true_off > 1.5 * limit) > 40 and np.sum(true_off < 0.5 * limit) > 20  # both met
    assert not np.any(is_flagged[(t > 0.5) & (t < 0.54) & (trip < 1e-3)])
    assert np.all(is_flagged[(t > 0.98) & (t < 1.02)]) and np.any((t > 0.98) & (t < 1.02) & (trip < 1e-3))


def test_a_dial_landing_between_its_readings_is_flagged_not_stored_off():
    """The tool lands on the edge mid-pass (the dial's reading swings by 1 mm within about 10 ms,
    read every 5 ms): rows whose interpolated dial may be off by more than the line noise are
    flagged ``dial changing fast``; every stored row's dial is the true one within that noise,
    and the rows away from the landing are all stored."""

    def true_dial(t):
        return 0.1 - 0.5 * (1.0 - np.tanh((t - 0.5) / 0.004))  # a logistic step, 0.002 s scale

    t_dial = np.arange(0.0, 2.0, 0.005)
    streams = _Streams(t_dial, true_dial(t_dial))
    session = _session(streams, max_speed=1e5)
    rows, flagged, _ = session._rows(_Run(0, 0.0, 2.0, 0.0, 1.0), streams.robot_arrays)
    t_rows = np.array([r["t_s"] for r in rows])
    dial = np.array([r["dial_mm"] for r in rows])
    assert np.max(np.abs(dial - true_dial(t_rows))) <= RULES["dial_limit_mm"]
    fast = [f["t_s"] for f in flagged if f["reason"] == "dial changing fast"]
    assert fast and all(0.45 < t < 0.55 for t in fast)
    t_read = np.array(streams.sensors["drawstring"].t) - RULES["latency_s"]["drawstring"]
    away = lambda t: (t < 0.45) | (t > 0.55)  # noqa: E731
    assert away(t_rows).sum() == away(t_read).sum()
