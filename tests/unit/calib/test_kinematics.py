import numpy as np

from calib.kinematics import N_DH, parallel_axis_pairs, tcp_jacobian, tcp_position
from calib.params import dh_from_degrees
from sim_fixtures.world import NOMINAL_JR680, Robot


def _random_dh(rng):
    return np.column_stack(
        [
            rng.uniform(-np.pi, np.pi, 6),
            rng.uniform(-500, 500, 6),
            rng.uniform(-500, 500, 6),
            rng.uniform(-np.pi, np.pi, 6),
        ]
    )


def test_contract_reference_pose():
    dh = dh_from_degrees(NOMINAL_JR680[:, [3, 2, 1, 0]])
    p = tcp_position(dh, np.radians([[0, -50, -20, 0, -90, 0]]), np.zeros(3))[0]
    np.testing.assert_allclose(p, [-1053.0, 0.0, 145.5], atol=0.1)


def test_matches_independent_sim_kinematics(rng):
    table = NOMINAL_JR680 + rng.normal(0, 1, NOMINAL_JR680.shape)
    robot = Robot(table, tool=np.array([10.0, -5.0, 30.0]))
    q = rng.uniform(-180, 180, (20, 6))
    dh = dh_from_degrees(table[:, [3, 2, 1, 0]])
    np.testing.assert_allclose(tcp_position(dh, np.radians(q), robot.tool), robot.tcp(q), atol=1e-9)


def test_jacobian_matches_finite_differences(rng):
    dh, q, tool = _random_dh(rng), rng.uniform(-np.pi, np.pi, (8, 6)), rng.uniform(-100, 100, 3)
    _, jac = tcp_jacobian(dh, q, tool)
    x, h = dh.ravel(), 1e-6
    for k in range(N_DH):
        dx = np.zeros(N_DH)
        dx[k] = h
        fd = (
            tcp_position((x + dx).reshape(6, 4), q, tool) - tcp_position((x - dx).reshape(6, 4), q, tool)
        ) / (2 * h)
        np.testing.assert_allclose(jac[:, :, k], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))


def test_parallel_axes_of_jr680():
    dh = dh_from_degrees(NOMINAL_JR680[:, [3, 2, 1, 0]])
    assert parallel_axis_pairs(dh) == [1]  # alpha_2 = 0: joints 2 and 3 are parallel
