"""calib.sweep: the linear moves of a pass, their timing within the limits, the rows they sweep."""

import numpy as np
import pytest

from calib import ik
from calib.sweep import (
    PassShape,
    SweepLimits,
    continuous,
    joint_move_s,
    line_passes,
    rotation_angle,
    segment_durations,
    slerp,
    swept_rows,
)
from sim_fixtures.world import DEFAULT_LINES, JR680_FILE, Robot


def _rz(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_slerp_turns_uniformly_about_one_axis_from_one_end_to_the_other():
    r0, r1 = np.eye(3), _rz(np.radians(90.0))
    out = slerp(r0, r1, np.array([0.0, 0.5, 1.0]))
    assert np.allclose(out[0], r0) and np.allclose(out[2], r1)
    assert np.allclose(out[1], _rz(np.radians(45.0)))
    assert np.degrees(rotation_angle(r0, out[1])) == pytest.approx(45.0)


def test_a_segment_takes_the_longer_of_its_length_at_the_speed_and_its_turn_at_the_rate():
    limits = SweepLimits(tcp_mm_s=20.0, turn_deg_s=10.0)
    position = np.array([[0.0, 0, 0], [100.0, 0, 0], [110.0, 0, 0]])
    rotation = np.stack([np.eye(3), np.eye(3), _rz(np.radians(30.0))])
    assert segment_durations(position, rotation, limits) == pytest.approx([5.0, 3.0])


def test_continuous_waypoints_turn_the_short_way_and_stay_inside_the_limits():
    limits = np.radians(np.tile([-360.0, 360.0], (6, 1)))
    q = np.radians(np.array([[0, 0, 0, 0, 0, 170.0], [0, 0, 0, 0, 0, -170.0]]))
    assert np.degrees(continuous(q, limits)[:, 5]) == pytest.approx([170.0, 190.0])


def test_a_joint_move_follows_its_trapezoid():
    assert joint_move_s(np.zeros(6), np.full(6, 1.0), 0.5, 1.0) == pytest.approx(2.0 + 0.5)
    assert joint_move_s(np.zeros(6), np.full(6, 0.01), 0.5, 1.0) == pytest.approx(0.2)


@pytest.fixture(scope="module")
def jr680():
    robot = Robot.from_file(JR680_FILE)
    return robot.dh, robot.tool, np.radians(robot.limits_deg)


def test_every_swept_row_lies_on_the_edge_and_the_pass_keeps_to_its_limits(jr680):
    dh, tool, limits = jr680
    gauge = DEFAULT_LINES[0]
    line = (gauge.centre, gauge.direction, gauge.length_mm, gauge.approach)
    sweep = SweepLimits()
    (waypoints,) = line_passes(dh, tool, limits, line, PassShape(), sweep, np.random.default_rng(1), 1)
    rows = swept_rows(dh, tool, limits, waypoints, sweep)
    assert rows.valid.all()
    p, rot = ik.tool_frames(dh, rows.q, tool)
    rel = p - gauge.centre
    off_line = rel - (rel @ gauge.direction)[:, None] * gauge.direction
    assert np.abs(off_line).max() < 1e-3  # mm: the solver's tolerance, far below the dial's 2 um
    along = rel @ gauge.direction
    assert along.min() == pytest.approx(-gauge.length_mm / 2, abs=1e-3)
    assert along.max() == pytest.approx(gauge.length_mm / 2, abs=1e-3)
    dt = np.diff(rows.t_s)
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / dt
    turn = np.degrees(rotation_angle(rot[:-1], rot[1:])) / dt
    assert speed.max() <= sweep.tcp_mm_s * 1.001 and turn.max() <= sweep.turn_deg_s * 1.001
    assert rows.duration_s >= gauge.length_mm / sweep.tcp_mm_s
    assert len(rows.q) == pytest.approx(rows.duration_s * sweep.row_hz, abs=2.0)  # and the end row
    assert np.degrees(np.abs(np.diff(rows.q, axis=0))).max() < 2.0  # no joint jumps between rows


def test_no_pass_is_drawn_where_the_arm_cannot_reach_the_line(jr680):
    dh, tool, limits = jr680
    far = (np.array([5000.0, 0, 0]), np.array([0, 1.0, 0]), 400.0, np.array([0, 0, -1.0]))
    assert line_passes(dh, tool, limits, far, PassShape(), SweepLimits(), np.random.default_rng(0), 1) == []
