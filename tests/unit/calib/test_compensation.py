"""Program compensation on a known pair of models: the calibrated one reaches the nominal poses,
rows keep their branch, and rows that cannot be compensated keep their joints and say why."""

import numpy as np
import pytest

import configs
from calib.compensation import CompensationOptions, Status, compensate
from calib.ik import NewtonOptions, solve, solve_pose, tool_frames
from calib.joint_terms import JointTerms, Term
from calib.params import dh_from_degrees
from calib.robot_model import RobotModel
from station.formats.tables import load_robot

JR680 = load_robot(configs.path("robots/hsr_jr680.toml"))  # the paper's Table I
TOOL = np.array([10.0, -5.0, 120.0])


@pytest.fixture(scope="module")
def pair():
    """The nominal JR680 and a 'calibrated' one off by a built robot's errors (0.15 deg, 0.75 mm)."""
    rng = np.random.default_rng(7)
    error = rng.normal(0, [0.15, 0.75, 0.75, 0.15], (6, 4))
    limits = np.radians(JR680.limits_deg())
    nominal = RobotModel(dh_from_degrees(JR680.table_deg()), TOOL, limits)
    calibrated = RobotModel(dh_from_degrees(JR680.table_deg() + error), TOOL, limits)
    q = rng.uniform(limits[:, 0], limits[:, 1], (2000, 6))
    return nominal, calibrated, q, compensate(nominal, calibrated, q)


def test_compensated_rows_reach_the_meant_pose(pair):
    nominal, calibrated, q, comp = pair
    ok = comp.status == Status.OK
    assert ok.mean() > 0.7
    p_meant, r_meant = nominal.tool_frames(q[ok])
    p, r = calibrated.tool_frames(comp.q[ok])
    assert np.linalg.norm(p - p_meant, axis=1).max() < 1e-3  # 1 um
    angle = np.arccos(np.clip((np.einsum("nij,nij->n", r, r_meant) - 1) / 2, -1, 1))
    assert np.degrees(angle).max() < 1e-4
    # without compensation the calibrated robot misses by millimetres
    assert np.median(np.linalg.norm(calibrated.tool_frames(q[ok])[0] - p_meant, axis=1)) > 1.0


def test_the_branch_is_kept(pair):
    """Small joint moves only, and the wrist stays on its side (no flip of q5 + theta5)."""
    nominal, _, q, comp = pair
    ok = comp.status == Status.OK
    assert np.degrees(np.abs(comp.q[ok] - q[ok]).max()) <= 5.0
    theta5 = nominal.dh[4, 0]
    assert np.all(np.sign(np.sin(comp.q[ok, 4] + theta5)) == np.sign(np.sin(q[ok, 4] + theta5)))


def test_rows_that_cannot_be_compensated_keep_their_joints(pair):
    _, _, q, comp = pair
    kept = comp.status != Status.OK
    np.testing.assert_array_equal(comp.q[kept], q[kept])
    assert np.all(comp.shift[kept] == 0.0)
    wrist = comp.status == Status.WRIST_SINGULARITY
    assert wrist.any() and np.all(comp.wrist_angle[wrist] < np.radians(10.0))
    assert np.all(comp.wrist_angle[comp.status == Status.OK] >= np.radians(10.0))


def test_limits_and_singularity_statuses(pair):
    nominal, calibrated, _, _ = pair
    q = np.radians(
        [
            [0, -50, -20, 0, -40, 0],  # an ordinary working pose
            [0, 95, -20, 0, -40, 0],  # q2 above its 90 deg limit
            [0, -50, -20, 30, -90, 10],  # q5 + theta5 = 0: axes 4 and 6 aligned
            [0, -50, -20, 0, -134.999, 0],  # at q5's limit: compensating may leave it
        ]
    )
    comp = compensate(nominal, calibrated, q)
    assert comp.status[0] == Status.OK
    assert comp.status[1] == Status.OUTSIDE_LIMITS and comp.limit_joint[1] == 1
    assert comp.status[2] == Status.WRIST_SINGULARITY
    assert comp.status[3] in (Status.OK, Status.LEAVES_LIMITS)
    if comp.status[3] == Status.LEAVES_LIMITS:
        assert comp.limit_joint[3] == 4


def test_a_row_beyond_reach_is_not_converged(pair):
    """A calibrated arm 20 mm shorter cannot reach the stretched nominal pose."""
    nominal, _, _, _ = pair
    shorter = RobotModel(
        nominal.dh - np.array([0, 0, 20.0, 0]) * (np.arange(6) == 1)[:, None], TOOL, nominal.limits
    )
    q = np.radians([[0, -90, 90, 0, -45, 0]])  # upper arm and forearm in line: stretched
    comp = compensate(nominal, shorter, q, CompensationOptions(max_joint_change=np.radians(90)))
    assert comp.status[0] == Status.NOT_CONVERGED
    assert comp.position_error[0] > 1.0


def test_same_model_changes_nothing(pair):
    nominal, _, q, _ = pair
    comp = compensate(nominal, nominal, q[:200])
    ok = comp.status == Status.OK
    np.testing.assert_allclose(comp.q[ok], q[:200][ok], atol=1e-12)
    assert comp.shift.max() < 1e-9


def test_solve_keeps_its_behaviour_and_solve_pose_stops_at_tolerance(pair):
    """``ik.solve`` runs every iteration; ``solve_pose`` with tolerances stops once reached, at
    the same solution."""
    nominal, calibrated, q, _ = pair
    dh, tool = calibrated.dh, calibrated.tool
    p, r = nominal.tool_frames(q[:50])
    q_all, err = solve(dh, tool, p, r, q[:50])
    np.testing.assert_allclose(tool_frames(dh, q_all, tool)[0][err < 1e-6], p[err < 1e-6], atol=1e-6)
    reached = np.flatnonzero(err < 1e-6)
    assert len(reached) > 35
    options = NewtonOptions(position_tol=1e-6, orientation_tol=1e-9)
    stopped = solve_pose(
        calibrated.tool_frames, calibrated.jacobian, p[reached], r[reached], q[reached], options
    )
    assert stopped.iterations < 10
    assert stopped.position_error.max() <= 1e-6 and stopped.orientation_error.max() <= 1e-9
    np.testing.assert_allclose(stopped.q, q_all[reached], atol=1e-6)  # 1 um at a metre


def test_compensation_takes_the_joint_terms_along(pair):
    """A calibrated model whose joints yield and whose joint 2 has a harmonic: the compensated rows
    reach the meant pose through the angles the links take, not merely through the table."""
    nominal, calibrated, q, _ = pair
    terms = JointTerms([Term(1, "sin1_deg"), Term(2, "cos2_deg")], calibrated.dh)
    with_terms = RobotModel(
        calibrated.dh, calibrated.tool, calibrated.limits, terms, np.radians([0.05, -0.03])
    )
    comp = compensate(nominal, with_terms, q[:300])
    ok = comp.status == Status.OK
    p_meant = nominal.tool_frames(q[:300][ok])[0]
    assert np.linalg.norm(with_terms.tool_frames(comp.q[ok])[0] - p_meant, axis=1).max() < 1e-3
    # the terms matter: the table alone would put those joints off by their deflection
    assert np.median(np.linalg.norm(calibrated.tool_frames(comp.q[ok])[0] - p_meant, axis=1)) > 0.1
