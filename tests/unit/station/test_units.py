"""``station.formats.units``: a unit mistake is recognised over a whole file, and a correct file
whose values happen to be small in places is not mistaken for one."""

import numpy as np
import pytest

from errors import InputError
from station.formats.units import check_joints_in_degrees, check_positions_in_mm, check_robot_units

UR10_ALPHA = np.array([90.0, 0.0, 0.0, 90.0, -90.0, 0.0])


def _table(alpha):
    return np.column_stack([np.zeros(6), np.ones(6), np.ones(6), alpha])


def test_joints_all_within_two_pi_are_radians_but_one_small_joint_is_not():
    rng = np.random.default_rng(0)
    q = rng.uniform(-170, 170, (50, 6))
    check_joints_in_degrees("s.csv", q, "rows")
    q[:, 5] = rng.uniform(-3, 3, 50)  # one joint barely moved: still degrees
    check_joints_in_degrees("s.csv", q, "rows")
    check_joints_in_degrees("p.csv", np.zeros((1, 6)), "program rows")  # a home pose is no evidence
    with pytest.raises(InputError, match="look like radians"):
        check_joints_in_degrees("s.csv", np.radians(q), "rows")


def test_twists_or_limits_in_radians_are_named_and_degrees_pass():
    limits = np.tile([-360.0, 360.0], (6, 1))
    check_robot_units("r.toml", _table(UR10_ALPHA), limits)
    check_robot_units("r.toml", _table(np.zeros(6)), limits)  # all-zero twists: no evidence either way
    with pytest.raises(InputError, match="alpha_deg are all within"):
        check_robot_units("r.toml", _table(np.radians(UR10_ALPHA)), limits)
    limits[2] = [-3.0, 3.0]
    with pytest.raises(InputError, match="joints.2: q_min_deg -3 .. q_max_deg 3 spans 6 deg"):
        check_robot_units("r.toml", _table(UR10_ALPHA), limits)


def test_points_all_near_the_base_are_metres_one_near_point_is_not():
    points = {"lines.0.point_mm": [-1100.0, 0.0, 150.0], "lines.1.point_mm": [5.0, 0.0, 0.0]}
    check_positions_in_mm("s.toml", points)
    check_positions_in_mm("s.toml", {})
    with pytest.raises(InputError, match=r"\[-1.1, 0.0, 0.15\]\): these look like metres"):
        check_positions_in_mm("s.toml", {"lines.0.point_mm": [-1.1, 0.0, 0.15]})
