"""calib's D-H kinematics, the project's only one (the simulator uses it too), checked independently:
the contract's reference pose, a second formulation built from elementary motions with scipy's
``Rotation``, and the analytic Jacobians against finite differences."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib import ik, kinematics
from calib.kinematics import (
    N_DH,
    base_from_frames,
    dh_table,
    parallel_axis_pairs,
    tcp_jacobian,
    tcp_jacobian_by_axes,
    tcp_position,
    tcp_position_by_axes,
)
from sim_fixtures.world import JR680_FILE, Robot


def _random_dh(rng):
    return np.column_stack(
        [
            rng.uniform(-np.pi, np.pi, 6),
            rng.uniform(-500, 500, 6),
            rng.uniform(-500, 500, 6),
            rng.uniform(-np.pi, np.pi, 6),
        ]
    )


def _composed_frames(dh, q):
    """Frames 1..6 as (rotations, origins [mm]), composed motion by motion as the contract states
    ``A_i = Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``: a rotation turns the frame, a
    translation moves its origin along the frame's own axis. No 4x4 matrix, no D-H entries."""
    rot, origin = Rotation.identity(len(q)), np.zeros((len(q), 3))
    out = []
    for (theta, d, a, alpha), qi in zip(dh, q.T, strict=True):
        rot = rot * Rotation.from_euler("z", (theta + qi)[:, None])
        origin = origin + rot.apply([0.0, 0.0, d])
        origin = origin + rot.apply([a, 0.0, 0.0])
        rot = rot * Rotation.from_euler("x", np.full((len(q), 1), alpha))
        out.append((rot, origin))
    return out


def test_contract_reference_pose():
    dh = Robot.from_file(JR680_FILE).dh
    p = tcp_position(dh, np.radians([[0, -50, -20, 0, -90, 0]]), np.zeros(3))[0]
    np.testing.assert_allclose(p, [-1053.0, 0.0, 145.5], atol=0.1)


@pytest.mark.parametrize("seed", range(5))
def test_matches_elementary_motions_composed_with_scipy(seed):
    rng = np.random.default_rng(seed)
    dh, q, tool = _random_dh(rng), rng.uniform(-np.pi, np.pi, (20, 6)), rng.uniform(-200, 200, 3)
    frames = base_from_frames(dh, q)
    reference = _composed_frames(dh, q)
    np.testing.assert_allclose(frames[:, 0], np.broadcast_to(np.eye(4), (20, 4, 4)))
    for i, (rot, origin) in enumerate(reference, start=1):
        np.testing.assert_allclose(frames[:, i, :3, :3], rot.as_matrix(), atol=1e-12)
        np.testing.assert_allclose(frames[:, i, :3, 3], origin, atol=1e-9)
        np.testing.assert_allclose(frames[:, i, 3], np.broadcast_to([0, 0, 0, 1.0], (20, 4)))
    flange_rot, flange = reference[-1]
    np.testing.assert_allclose(tcp_position(dh, q, tool), flange + flange_rot.apply(tool), atol=1e-9)


def test_jacobian_matches_finite_differences(rng):
    dh, q, tool = _random_dh(rng), rng.uniform(-np.pi, np.pi, (8, 6)), rng.uniform(-100, 100, 3)
    _, jac = tcp_jacobian(dh, q, tool)
    x, h = dh.ravel(), 1e-6
    for k in range(N_DH):
        dx = np.zeros(N_DH)
        dx[k] = h
        fd = (tcp_position(dh_table(x + dx), q, tool) - tcp_position(dh_table(x - dx), q, tool)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, k], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_blocks_of_rows_give_the_whole_arrays(rng, monkeypatch):
    """``KINEMATICS_ROWS`` at a time (3 here, 20 rows: a short last block) is row for row the same."""
    dh, q, tool = _random_dh(rng), rng.uniform(-np.pi, np.pi, (20, 6)), rng.uniform(-100, 100, 3)
    whole_p, (whole_jp, whole_jac) = tcp_position_by_axes(dh, q, tool), tcp_jacobian_by_axes(dh, q, tool)
    monkeypatch.setattr(kinematics, "KINEMATICS_ROWS", 3)
    p, jac = tcp_jacobian_by_axes(dh, q, tool)
    np.testing.assert_array_equal(tcp_position_by_axes(dh, q, tool), whole_p)
    np.testing.assert_array_equal(p, whole_jp)
    np.testing.assert_array_equal(jac, whole_jac)


def test_the_frame_axes_compose_the_products_frames(rng):
    """Both compositions give the same TCPs and derivatives (to the rounding of a few products of
    metre-sized lengths: 1e-12 relative)."""
    dh, q, tool = _random_dh(rng), rng.uniform(-np.pi, np.pi, (50, 6)), rng.uniform(-100, 100, 3)
    p, jac = tcp_jacobian(dh, q, tool)
    p_axes, jac_axes = tcp_jacobian_by_axes(dh, q, tool)
    np.testing.assert_allclose(tcp_position_by_axes(dh, q, tool), p, rtol=0, atol=1e-9)
    np.testing.assert_allclose(p_axes, p, rtol=0, atol=1e-9)
    np.testing.assert_allclose(jac_axes, jac, rtol=0, atol=1e-9)


def test_geometric_jacobian_matches_finite_differences(rng):
    """Linear rows: the TCP's derivative by each joint; angular rows (scaled): the rotation vector
    of ``R(q + h e_k) R(q - h e_k)^T`` over ``2 h``."""
    dh, q, tool = _random_dh(rng), rng.uniform(-np.pi, np.pi, (8, 6)), rng.uniform(-100, 100, 3)
    jac, h = ik.geometric_jacobian(dh, q, tool), 1e-6
    for k in range(6):
        dq = np.zeros(6)
        dq[k] = h
        (p_plus, r_plus), (p_minus, r_minus) = (
            ik.tool_frames(dh, q + dq, tool),
            ik.tool_frames(dh, q - dq, tool),
        )
        linear = (p_plus - p_minus) / (2 * h)
        angular = Rotation.from_matrix(r_plus @ r_minus.transpose(0, 2, 1)).as_rotvec() / (2 * h)
        np.testing.assert_allclose(jac[:, :3, k], linear, atol=1e-5 * np.abs(linear).max())
        np.testing.assert_allclose(jac[:, 3:, k], ik.LENGTH_SCALE * angular, atol=1e-3)


def test_ik_reaches_poses_of_the_forward_kinematics(rng):
    """Targets made by the forward kinematics at random configurations are reached from seeds
    10 deg away, to the tolerance asked; the pose error is zero at the configuration itself."""
    robot = Robot.from_file(JR680_FILE)
    tool = np.array([10.0, -5.0, 150.0])
    q_true = np.radians(rng.uniform(robot.limits_deg[:, 0] / 2, robot.limits_deg[:, 1] / 2, (30, 6)))
    q_true = q_true[ik.conditioning(robot.dh, q_true, tool) > 0.05]
    position, rotation = ik.tool_frames(robot.dh, q_true, tool)
    frames = lambda q: ik.tool_frames(robot.dh, q, tool)  # noqa: E731
    np.testing.assert_allclose(ik.pose_error(frames, q_true, position, rotation), 0.0, atol=1e-9)
    seeds = q_true + np.radians(rng.uniform(-10, 10, q_true.shape))
    q, err = ik.solve(robot.dh, tool, position, rotation, seeds, damping=1e-6, tol=1e-8)
    assert err.max() < 1e-8
    p, r = ik.tool_frames(robot.dh, q, tool)
    np.testing.assert_allclose(p, position, atol=1e-8)
    np.testing.assert_allclose(r, rotation, atol=1e-10)


def test_parallel_axes_of_jr680():
    dh = Robot.from_file(JR680_FILE).dh
    assert parallel_axis_pairs(dh) == [1]  # alpha_2 = 0: joints 2 and 3 are parallel
