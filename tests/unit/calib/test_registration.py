"""Registering a calibrated frame to the cell's through the gauge lines (``calib.registration``)."""

import numpy as np
from scipy.spatial.transform import Rotation

from calib.registration import register_lines

POINTS = np.array([[1000.0, 0, 300], [950, -450, 600], [1100, 400, 800]])
DIRECTIONS = np.array([[0, 1.0, 0], [1.0, 0, 0], [-0.2, 0, 1.0]]) / np.array([[1], [1], [np.hypot(0.2, 1)]])
LENGTHS = np.array([500.0, 400.0, 400.0])
MOTION = Rotation.from_rotvec(np.radians([0.3, -0.2, 0.25])).as_matrix(), np.array([3.0, -2.0, 4.5])


def _moved(points, directions, slide):
    """The lines in the other frame: moved by MOTION, each point slid along its line by ``slide`` [mm]
    (a line has no point of its own)."""
    rot, t = MOTION
    return points @ rot.T + t + slide[:, None] * (directions @ rot.T), directions @ rot.T


def test_two_lines_not_parallel_give_the_rigid_motion_back():
    to_points, to_dirs = _moved(POINTS, DIRECTIONS, np.array([40.0, -25.0, 10.0]))
    for k in ([0, 1], [0, 1, 2]):
        rot, t = register_lines(POINTS[k], DIRECTIONS[k], to_points[k], -to_dirs[k], LENGTHS[k])  # signs free
        np.testing.assert_allclose(rot, MOTION[0], atol=1e-4)  # 0.1 mm over a metre
        np.testing.assert_allclose(t, MOTION[1], atol=0.1)


def test_one_line_brings_it_onto_its_counterpart_and_leaves_the_rest_near_none():
    to_points, to_dirs = _moved(POINTS[:1], DIRECTIONS[:1], np.array([40.0]))
    rot, t = register_lines(POINTS[:1], DIRECTIONS[:1], to_points, to_dirs, LENGTHS[:1])
    moved = POINTS[0] @ rot.T + t - to_points[0]
    assert np.linalg.norm(moved - (moved @ to_dirs[0]) * to_dirs[0]) < 0.05  # onto the line
    np.testing.assert_allclose(np.cross(DIRECTIONS[0] @ rot.T, to_dirs[0]), 0, atol=1e-4)
    assert abs(t @ to_dirs[0]) < 1.0 and Rotation.from_matrix(rot).magnitude() < np.radians(1)  # the prior
