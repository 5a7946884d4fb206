"""The simulated cell: its nominal robot is the shipped file, the shipped sim setup states its noise
and lines, its configurations touch the lines, and its inverse kinematics says when a pose is out
of reach."""

import numpy as np
import pytest

import configs
from calib.joint_terms import JointTerms, Term
from sim_fixtures.world import JR680_FILE, JointError, Noise, Robot, World
from station.formats.tables import load_robot, load_setup

SIM_SETUP = configs.path("setups/sim.toml")


def test_nominal_robot_is_the_shipped_robot_file():
    """Read through station's validated reader, the shipped JR680 is the world's nominal robot,
    and the contract's reference pose puts its TCP near (-1053, 0, 146) mm."""
    shipped = load_robot(JR680_FILE)
    nominal = World.create(0).nominal
    np.testing.assert_array_equal(nominal.table_deg, shipped.table_deg())
    np.testing.assert_array_equal(nominal.limits_deg, shipped.limits_deg())
    np.testing.assert_array_equal(nominal.tool, shipped.tool_mm)
    assert nominal.tcp([0, -50, -20, 0, -90, 0]) == pytest.approx([-1053.0, 0.0, 146.0], abs=1.0)


def test_shipped_sim_setup_states_the_simulators_noise():
    """What a user reads in configs/setups/sim.toml (and the calibration whitens by) is the noise
    the simulated instruments add."""
    setup = load_setup(SIM_SETUP)
    assert setup.drawstring.sigma_mm == Noise().length_mm
    assert setup.dial.sigma_mm == Noise().dial_mm


def test_shipped_sim_setup_places_the_worlds_lines():
    """``station plan --setup configs/setups/sim.toml`` plans on the lines the world has."""
    stated = load_setup(SIM_SETUP).lines
    for line, true in zip(stated, World.create(0).lines, strict=True):
        assert line.id == true.id and line.length_mm == true.length_mm
        np.testing.assert_allclose(line.point_mm, true.centre)
        for given, unit in ((line.direction, true.direction), (line.approach, true.approach)):
            np.testing.assert_allclose(given / np.linalg.norm(given), unit, atol=1e-12)
        np.testing.assert_allclose(line.dial_axis, true.dial_axis, atol=1e-12)
        # the tool presses against the dial: it reads positive back along the approach (the
        # planner's default approach is minus the dial axis), on every line alike
        assert np.dot(line.approach, line.dial_axis) < -0.99 * np.linalg.norm(line.approach)


def test_line_configurations_touch_their_lines(rng):
    """The true TCP of every configuration lies on its line but for the operator's placement,
    which is along the dial axis and within its half width."""
    world = World.create(1)
    q, ids = world.line_configurations(6, rng)
    p = world.true_tcp_mm(q)
    for ln in world.lines:
        rel = p[ids == ln.id] - ln.centre
        off = rel - np.outer(rel @ ln.direction, ln.direction)
        along_dial = off @ ln.dial_axis
        np.testing.assert_allclose(off, np.outer(along_dial, ln.dial_axis), atol=1e-6)
        assert np.all(np.abs(along_dial) <= world.noise.placement_mm)
        assert np.all(np.abs(rel @ ln.direction) <= ln.length_mm / 2 + 1e-6)


def test_ik_reports_a_pose_outside_the_joint_limits_as_not_reached():
    robot = Robot.from_file(JR680_FILE)
    q = np.array([[10.0, -40.0, -10.0, 20.0, -60.0, 30.0], [10.0, -40.0, -10.0, 20.0, -60.0, 200.0]])
    targets = np.stack([robot.pose(qi) for qi in q])
    robot.limits_deg[5] = [-180.0, 180.0]
    q_found, reached = robot.ik(targets, q + 2.0)
    np.testing.assert_allclose(q_found, q, atol=1e-6)
    assert reached.tolist() == [True, False]


def test_joint_error_readings_put_the_links_where_the_truth_stands(rng):
    """A joint error makes the joints read q such that the links, at q plus the terms' deflection
    at q, stand at the true angles (to far below the joint noise, 0.0005 deg)."""
    dh = World.create(0).nominal.dh
    terms = JointTerms([Term(1, "sin1_deg"), Term(2, "cos2_deg"), Term(4, "sin2_deg")], dh)
    error = JointError(terms, np.radians([0.05, -0.03, 0.02]))
    q_true = rng.uniform(-90, 90, (20, 6))
    q = np.radians(error.readings_deg(q_true))
    links = terms.link_angles(q, error.values, terms.basis(q))
    np.testing.assert_allclose(np.degrees(links), q_true, atol=1e-9)
    assert np.abs(np.degrees(q) - q_true).max() > 0.01  # the readings do differ
