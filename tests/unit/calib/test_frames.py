"""D-H rows as URDF joint origins: closed forms, round trips and the gimbal case."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import configs
from calib.frames import chain_pose, joint_origins, matrix_from_rpy, rot_x, rot_z, rpy_from_matrix
from calib.kinematics import base_from_frames
from calib.params import dh_from_degrees
from station.formats.tables import load_robot

JR680 = load_robot(configs.path("robots/hsr_jr680.toml")).table_deg()  # theta, d, a, alpha (Table I)


def test_rpy_is_urdf_fixed_axis_xyz(rng):
    """URDF's rpy is rotation about fixed x, then y, then z: scipy's extrinsic 'xyz'."""
    for angles in rng.uniform(-np.pi, np.pi, (50, 3)) * [1, 0.5, 1]:
        expected = Rotation.from_euler("xyz", angles).as_matrix()
        np.testing.assert_allclose(matrix_from_rpy(angles), expected, atol=1e-14)
        np.testing.assert_allclose(rpy_from_matrix(expected), angles, atol=1e-12)


def test_rpy_round_trip_on_random_rotations():
    for rot in Rotation.random(500, random_state=1).as_matrix():
        rpy = rpy_from_matrix(rot)
        assert -np.pi / 2 <= rpy[1] <= np.pi / 2
        np.testing.assert_allclose(matrix_from_rpy(rpy), rot, atol=1e-13)


@pytest.mark.parametrize("sign", [1.0, -1.0])
@pytest.mark.parametrize("eps", [0.0, 1e-15, 1e-9, 1e-6])
def test_rpy_at_and_near_gimbal_lock(sign, eps):
    """At pitch = +-pi/2 roll and yaw turn about one axis: the angles still give the rotation."""
    rot = matrix_from_rpy((0.3, sign * (np.pi / 2 - eps), -0.7))
    np.testing.assert_allclose(matrix_from_rpy(rpy_from_matrix(rot)), rot, atol=1e-12)


def test_origins_compose_to_the_dh_chain(rng):
    """O_1 Rz(q_1) ... O_6 Rz(q_6) O_7 equals the contract's A_1 ... A_6 for perturbed tables."""
    for _ in range(20):
        table = JR680 + rng.normal(0, [0.5, 2.0, 2.0, 0.5], (6, 4))
        dh = dh_from_degrees(table)
        q = rng.uniform(-np.pi, np.pi, (10, 6))
        origins = joint_origins(dh)
        expected = base_from_frames(dh, q)[:, 6]
        for qi, want in zip(q, expected, strict=True):
            np.testing.assert_allclose(chain_pose(origins, qi), want, atol=1e-9)


def test_origin_closed_form():
    """O_i = Tx(a_{i-1}) Rx(alpha_{i-1}) Rz(theta_i) Tz(d_i): UR's wrist_3 (alpha5 = -90 deg, d6)."""
    dh = dh_from_degrees(JR680)
    o = joint_origins(dh)
    np.testing.assert_allclose(o[5][:3, 3], [0.0, 200.6, 0.0], atol=1e-12)  # Rx(-90) [0, 0, d6]
    np.testing.assert_allclose(o[5], rot_x(-np.pi / 2) @ _tz(200.6), atol=1e-12)
    np.testing.assert_allclose(o[0], rot_z(0.0) @ _tz(653.5), atol=1e-12)
    np.testing.assert_allclose(o[6], np.eye(4), atol=1e-12)  # a6 = alpha6 = 0


def _tz(d):
    out = np.eye(4)
    out[2, 3] = d
    return out
