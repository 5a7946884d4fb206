"""The simulated robot program: limits respected, dwells, cycles, hold, time scale and faults.

Motion is checked by sampling the program densely and differentiating numerically, so a profile
that broke a limit or jumped would fail here.
"""

import numpy as np
import pytest

from sim_fixtures.robot_program import (
    IDLE,
    RUNNING,
    RobotFault,
    SimRobot,
    move_duration,
    trapezoid,
)

TARGETS = np.array(
    [
        [0.0, -50.0, -20.0, 0.0, -90.0, 0.0],
        [60.0, -40.0, -30.0, 5.0, -80.0, 10.0],  # joint 1 leads: 60 deg
        [61.0, -40.5, -30.0, 5.0, -80.0, 10.0],  # short hop: triangular profile
    ]
)
SPEED, ACCEL, DWELL = 30.0, 60.0, 1.0


def robot(**kw):
    args = dict(speed_deg_s=SPEED, accel_deg_s2=ACCEL, dwell_s=DWELL)
    return SimRobot(TARGETS, **(args | kw))


def sample(rob, t_end, dt=1e-3):
    ts = np.arange(0.0, t_end, dt)
    states = [rob.state(t) for t in ts]
    return ts, np.array([s.q_deg for s in states]), np.array([s.qd_deg_s for s in states]), states


def test_documented_example_60_deg_takes_2_5_s():
    # 0.5 s up to 30 deg/s (7.5 deg), 1.5 s cruise (45 deg), 0.5 s braking (7.5 deg)
    assert move_duration(60.0, SPEED, ACCEL) == pytest.approx(2.5)
    assert trapezoid(60.0, 0.5, SPEED, ACCEL) == pytest.approx((7.5, 30.0))
    assert trapezoid(60.0, 2.0, SPEED, ACCEL) == pytest.approx((52.5, 30.0))
    assert trapezoid(60.0, 2.5, SPEED, ACCEL) == pytest.approx((60.0, 0.0))
    # 1 deg never reaches 30 deg/s: triangle with peak sqrt(L a) after sqrt(L / a)
    assert move_duration(1.0, SPEED, ACCEL) == pytest.approx(2 * np.sqrt(1 / 60))
    assert trapezoid(1.0, np.sqrt(1 / 60), SPEED, ACCEL) == pytest.approx((0.5, np.sqrt(60)))


def test_profile_respects_speed_and_acceleration_limits_on_every_joint():
    rob = robot()
    ts, q, qd, _ = sample(rob, rob.cycle_s, dt=1e-3)
    numeric_qd = np.diff(q, axis=0) / 1e-3
    assert np.abs(numeric_qd).max() <= SPEED * (1 + 1e-6)
    assert np.abs(qd).max() == pytest.approx(SPEED)  # the leading joint does reach v
    numeric_qdd = np.diff(qd, axis=0) / 1e-3
    assert np.abs(numeric_qdd).max() <= ACCEL * (1 + 1e-6)
    # reported velocity is the derivative of the reported position
    np.testing.assert_allclose(numeric_qd, 0.5 * (qd[1:] + qd[:-1]), atol=0.05)


def test_joints_are_synchronised_and_arrive_together():
    rob = robot()
    t_mid = DWELL + move_duration(60.0, SPEED, ACCEL) / 3
    st = rob.state(t_mid)
    frac = (st.q_deg - TARGETS[0]) / (TARGETS[1] - TARGETS[0])
    moving = TARGETS[1] != TARGETS[0]
    np.testing.assert_allclose(frac[moving], frac[moving][0])
    assert 0 < frac[moving][0] < 1 and not st.dwelling and st.target_index == 1


def test_dwells_at_each_target_then_cycles():
    rob = robot()
    m1 = move_duration(60.0, SPEED, ACCEL)
    m2 = move_duration(1.0, SPEED, ACCEL)
    m3 = move_duration(61.0, SPEED, ACCEL)
    assert rob.cycle_s == pytest.approx(3 * DWELL + m1 + m2 + m3)
    arrivals = [0.0, DWELL + m1, 2 * DWELL + m1 + m2]
    for k, t in enumerate(arrivals):
        for dt in (1e-6, DWELL / 2, DWELL - 1e-6):
            st = rob.state(t + dt)
            assert st.dwelling and st.target_index == k, (k, dt)
            np.testing.assert_array_equal(st.q_deg, TARGETS[k])
            np.testing.assert_array_equal(st.qd_deg_s, 0.0)
    later = rob.state(2 * rob.cycle_s + arrivals[1] + 0.3)
    assert later.dwelling and later.target_index == 1
    np.testing.assert_array_equal(later.q_deg, TARGETS[1])


def test_hold_keeps_the_robot_still_at_its_first_target():
    rob = robot(hold=True)
    for t in (0.0, 3.7, 1e4):
        st = rob.state(t)
        np.testing.assert_array_equal(st.q_deg, TARGETS[0])
        assert st.dwelling and st.target_index == 0 and st.robot_mode == RUNNING


def test_time_scale_plays_the_program_faster():
    slow, fast = robot(), robot(time_scale=10.0)
    for t in (0.05, 0.2, 0.47):
        np.testing.assert_allclose(fast.state(t).q_deg, slow.state(10 * t).q_deg)


def test_mode_fault_pauses_the_program_and_resumes_where_it_was():
    fault = RobotFault(start_s=1.5, end_s=3.5, robot_mode=IDLE)
    rob, ref = robot(faults=[fault]), robot()
    inside = [rob.state(t) for t in (1.6, 2.5, 3.4)]
    assert all(s.robot_mode == IDLE for s in inside)
    for s in inside:
        np.testing.assert_allclose(s.q_deg, ref.state(1.5).q_deg)
        np.testing.assert_array_equal(s.qd_deg_s, 0.0)
    after = rob.state(4.0)
    assert after.robot_mode == RUNNING
    np.testing.assert_allclose(after.q_deg, ref.state(2.0).q_deg)


def test_jitter_fault_never_settles_and_is_reproducible():
    fault = RobotFault(start_s=0.0, end_s=100.0, jitter_deg=0.05)
    a = robot(hold=True, faults=[fault], rng=np.random.default_rng(7))
    b = robot(hold=True, faults=[fault], rng=np.random.default_rng(7))
    qa = np.array([a.state(t).q_deg for t in np.linspace(0, 1, 200)])
    qb = np.array([b.state(t).q_deg for t in np.linspace(0, 1, 200)])
    np.testing.assert_array_equal(qa, qb)
    assert 0.03 < (qa - TARGETS[0]).std() < 0.07


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(speed_deg_s=0.0), "speed_deg_s"),
        (dict(dwell_s=-1.0), "dwell_s"),
        (dict(faults=[RobotFault(0, 1, jitter_deg=0.1)]), "rng"),
    ],
)
def test_bad_arguments_are_named(kw, message):
    with pytest.raises(ValueError, match=message):
        robot(**kw)
    with pytest.raises(ValueError, match="shape"):
        SimRobot(np.zeros((3, 5)), speed_deg_s=1, accel_deg_s2=1, dwell_s=1)


def test_a_program_run_once_waits_at_home_and_stands_at_its_first_target_after_the_cycle():
    from sim_fixtures.robot_program import HOME_LIFT_DEG, SimRobot, move_duration

    targets = [[0.0] * 6, [10.0] * 6]
    robot = SimRobot(targets, speed_deg_s=30.0, accel_deg_s2=60.0, dwell_s=1.0, once=True)
    waiting = robot.state(-1.0)  # before play: home, off the plan (no session takes it for target 0)
    assert np.allclose(waiting.q_deg, [0.0, HOME_LIFT_DEG, 0, 0, 0, 0]) and not waiting.qd_deg_s.any()
    assert HOME_LIFT_DEG > 2.0  # the session's default match_deg
    lead = move_duration(HOME_LIFT_DEG, 30.0, 60.0)
    first = robot.state(lead / 2)  # on its way to target 0
    assert first.target_index == 0 and not first.dwelling and first.qd_deg_s[1] < 0
    assert robot.state(lead + robot.cycle_s * 0.4).target_index == 1  # going round the first time
    for t in (lead + robot.cycle_s + 0.01, lead + 3 * robot.cycle_s + 0.5):
        state = robot.state(t)
        assert state.target_index == 0 and state.dwelling and not state.qd_deg_s.any()
        assert np.allclose(state.q_deg, 0.0)
    again = SimRobot(targets, speed_deg_s=30.0, accel_deg_s2=60.0, dwell_s=1.0)
    assert again.state(again.cycle_s * 1.4).target_index == 1  # round and round


def test_a_program_run_once_asks_for_its_first_target_as_it_starts_and_goes_where_it_is_corrected():
    from sim_fixtures.robot_program import SimRobot

    asked = []

    def retarget(k, prog_s):
        asked.append((k, prog_s))
        return np.full(6, 1.0) if k == 0 else None

    targets = [[0.0] * 6, [10.0] * 6]
    robot = SimRobot(targets, speed_deg_s=30.0, accel_deg_s2=60.0, dwell_s=1.0, once=True, retarget=retarget)
    robot.state(-1.0)
    assert asked == []  # not before play
    for t in (1.0, robot.cycle_s + 5.0):  # dwelling at target 0 (the corrected joints), and after the cycle
        state = robot.state(t)
        assert state.target_index == 0 and state.dwelling and np.allclose(state.q_deg, 1.0)
    assert asked[0] == (0, 0.0) and [k for k, _ in asked] == [0, 1]  # each asked once, target 0 at the start
