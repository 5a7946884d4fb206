"""The compliances of joints 2 and 3 under a load at the TCP (``calib.compliance``) against
independent truths: the lever arm is the work gravity does per turn of the joint, turned readings
move the TCP as the response says, and the simulated cell's sag (``sim_fixtures.unmodelled``: the
TCP drops with the square of its reach) is such a deflection where the cell works."""

import numpy as np
import pytest

from calib.compliance import COMPLIANT_JOINTS, compliance_response, compliance_turn_rad, gravity_lever_m
from calib.kinematics import THETA, tcp_jacobian, tcp_position
from calib.residual_map import table_response
from sim_fixtures.unmodelled import UR10_LIKE, Unmodelled
from sim_fixtures.world import World

SAG = Unmodelled((), UR10_LIKE.sag_mm_per_m2)


def cell(seed: int, lines: bool):
    """A simulated JR680's true table, TCP and readings [rad]: its gauge lines' contacts, or the
    whole workspace."""
    world, rng = World.create(seed), np.random.default_rng(seed)
    q_deg = world.line_configurations(100, rng)[0] if lines else world.random_configurations(300, rng)
    return world.true.dh, world.true.tool, np.radians(q_deg)


def test_the_lever_arm_is_the_work_gravity_does_per_turn_of_the_joint():
    # a 1 N load's torque about a joint is minus its height's derivative by the angle [m]
    dh, tool, q = cell(0, lines=False)
    _, jac = tcp_jacobian(dh, q, tool)
    want = -jac[:, 2, [4 * j + THETA for j in COMPLIANT_JOINTS]] / 1000.0
    np.testing.assert_allclose(gravity_lever_m(dh, q, tool), want, atol=1e-12)
    assert np.max(np.abs(want)) > 1.0  # the arm reaches over a metre: the check is not of zeros


def test_readings_turned_by_the_compliances_move_the_tcp_as_their_response_says():
    dh, tool, q = cell(1, lines=False)
    c = np.array([2e-4, -1e-4])
    moved = tcp_position(dh, compliance_turn_rad(dh, q, tool, c), tool) - tcp_position(dh, q, tool)
    _, jac = tcp_jacobian(dh, q, tool)
    # first order in the turn (about 3e-4 rad): what is left is that times the move
    assert np.max(np.abs(moved - compliance_response(dh, q, tool, jac) @ c)) < 1e-3 * np.max(np.abs(moved))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_simulated_sag_is_a_compliance_where_the_cell_works(seed):
    # where the lines are, the table (and the base frame) take most of the sag in and leave some
    # 4 %, the compliances beside it 0.5 %; over the whole workspace a drop with the reach alone,
    # whatever the joints, is no joint's deflection (they leave 40 % there)
    left = {lines: sag_left(seed, lines) for lines in (True, False)}
    table, both = left[True]
    assert both < 0.01 and table > 3 * both
    assert left[False][1] > 0.25


def sag_left(seed: int, lines: bool) -> tuple[float, float]:
    """What least squares leaves of the simulated sag (a share of its RMS) with the table's
    unknowns alone, and with the compliances beside them."""
    dh, tool, q = cell(seed, lines)
    p, jac = tcp_jacobian(dh, q, tool)
    sag = SAG.tcp_mm(dh, q, tool) - p
    table = table_response(dh, q, p, jac)
    both = np.concatenate([table, compliance_response(dh, q, tool, jac)], axis=2)
    fits = (np.linalg.lstsq(a.reshape(-1, a.shape[2]), sag.ravel(), rcond=None)[0] for a in (table, both))
    return tuple(rms(sag - a @ x) / rms(sag) for a, x in zip((table, both), fits, strict=True))


def rms(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
