"""Fixtures the program tests share."""

import numpy as np
import pytest

import configs
from sim_fixtures.world import GaugeLine, Robot, World
from station.formats.plan import Plan
from station.formats.tables import load_robot
from station.jobs.planning import contact_poses

LINE = GaugeLine(
    0, np.array([1000.0, 0, 300]), np.array([0, 1.0, 0]), 400.0, np.array([0, 0, 1.0]), np.array([0, 0, -1.0])
)


@pytest.fixture(scope="module")
def irb_plan():
    """The ABB IRB 2600 and a plan of 8 targets on one gauge line, with contact poses and approach."""
    robot = load_robot(configs.path("robots/abb_irb2600.toml"))
    nominal = Robot(robot.table_deg(), np.zeros(3), robot.limits_deg())
    world = World(nominal, nominal, np.zeros(3), 0.0, (LINE,))
    q, lines = world.line_configurations(8, np.random.default_rng(0), max_tilt_deg=10.0)
    pose = contact_poses(robot, np.radians(q))
    return robot, Plan(np.arange(8), lines, q, pose, np.tile(LINE.approach, (8, 1)))
