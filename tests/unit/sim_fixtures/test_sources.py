"""The simulated devices' source of truth: the cell's plan and dial, the instrument model, and the
robot program feeding the cell."""

import numpy as np
import pytest

from sim_fixtures.robot_program import SimRobot
from sim_fixtures.sources import CellSource
from sim_fixtures.station_sim import make_cell
from sim_fixtures.world import Noise


def test_plan_targets_touch_the_edge_and_the_dial_reads_height():
    cell = make_cell(0, 5)  # the world: the dial reads the operator's placement offset, <= 0.3 mm
    dial = cell.true_dial_mm(cell.plan_deg, cell.plan_lines)
    assert np.all(np.abs(dial) <= cell.world.noise.placement_mm) and np.std(dial) > 0
    raised = cell.plan_deg[:1] + np.array([0, 0, -1.0, 0, 0, 0])  # elbow: tool moves
    assert abs(cell.true_dial_mm(raised, [0])[0]) > 1.0


def test_instrument_noise_and_resolution():
    noise = Noise()
    inst = noise.drawstring(np.random.default_rng(1))
    values = np.array([inst.measure(100.0) for _ in range(2000)])
    # 2000 draws: the mean to 4.5 standard errors, the standard deviation to 10 % (6 of its errors)
    assert abs(values.mean() - 100.0) < 0.1 * noise.length_mm
    assert abs(values.std() / noise.length_mm - 1) < 0.1
    assert np.allclose(values * 1000, np.round(values * 1000))


def test_cell_source_follows_the_robot_program():
    cell = make_cell(0, 5)
    robot = SimRobot(cell.plan_deg, speed_deg_s=30, accel_deg_s2=60, dwell_s=1.0, time_scale=1.0)
    still, moving = CellSource(robot, cell).state(0.5), CellSource(robot, cell).state(1.3)
    assert still.q_deg == tuple(cell.plan_deg[0]) and still.qd_deg_s == (0.0,) * 6
    assert still.length_mm == pytest.approx(cell.true_length_mm(cell.plan_deg[0])[0])
    assert max(map(abs, moving.qd_deg_s)) > 0 and moving.length_mm != still.length_mm
