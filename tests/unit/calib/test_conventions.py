"""A controller's joint convention (``q_model = sign * reading + offset``): the maps, and the
mistake finder that names a flipped sign or a joint's zero off from settles that match no target."""

import numpy as np
import pytest

from calib.conventions import controller_joints, convention_mistake, model_joints

KUKA_SIGN = np.array([-1, 1, 1, -1, 1, -1])
KUKA_OFFSET = np.array([0.0, -90.0, 90.0, 0.0, 0.0, 0.0])
MATCH_DEG = 2.0
NOISE_DEG = 0.01  # a settle's spread about its target: far inside MATCH_DEG


def targets(n=40, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-150, 150, (n, 6))


def test_the_maps_are_each_others_inverse_and_follow_the_contract():
    q = targets(10)
    reading = controller_joints(q, KUKA_SIGN, KUKA_OFFSET)
    assert np.allclose(reading, KUKA_SIGN * (q - KUKA_OFFSET))
    assert np.allclose(model_joints(reading, KUKA_SIGN, KUKA_OFFSET), q, atol=1e-12)
    assert np.allclose(model_joints(reading, KUKA_SIGN, KUKA_OFFSET), KUKA_SIGN * reading + KUKA_OFFSET)


def settles_read_with(true_sign, true_offset, file_sign, file_offset, rows, seed=1):
    """Settles at plan rows ``rows``, as a station reads them under the file's convention while the
    controller's is the true one."""
    plan = targets()
    q_true = plan[rows] + np.random.default_rng(seed).normal(0, NOISE_DEG, (len(rows), 6))
    reading = controller_joints(q_true, true_sign, true_offset)
    return plan, model_joints(reading, file_sign, file_offset)


@pytest.mark.parametrize("flipped", [(0,), (0, 3, 5), (1, 2), (5,)])
def test_flipped_signs_are_named_with_the_convention_that_puts_the_settles_on_their_targets(flipped):
    true_sign = KUKA_SIGN.copy()
    file_sign = true_sign.copy()
    file_sign[list(flipped)] *= -1
    rows = [5, 9, 12]
    plan, settled = settles_read_with(true_sign, KUKA_OFFSET, file_sign, KUKA_OFFSET, rows)
    found = convention_mistake(settled, plan, MATCH_DEG, file_sign, KUKA_OFFSET)
    assert found is not None and found.flipped == flipped and found.shifted is None
    assert np.array_equal(found.joint_sign, true_sign)
    assert np.array_equal(found.joint_offset_deg, KUKA_OFFSET)
    assert found.targets.tolist() == rows


@pytest.mark.parametrize("shift", [180.0, -360.0, 90.0, 37.5])
def test_a_joint_zero_off_by_a_constant_is_named(shift):
    file_offset = KUKA_OFFSET.copy()
    file_offset[2] -= shift  # the file's joint 3 zero is off: the settles read shift too low
    rows = [1, 2, 30, 31]
    plan, settled = settles_read_with(KUKA_SIGN, KUKA_OFFSET, KUKA_SIGN, file_offset, rows)
    found = convention_mistake(settled, plan, MATCH_DEG, KUKA_SIGN, file_offset)
    assert found is not None and found.shifted[0] == 2 and found.flipped == ()
    assert found.shifted[1] == pytest.approx(shift, abs=3 * NOISE_DEG)
    assert np.allclose(found.joint_offset_deg, KUKA_OFFSET, atol=3 * NOISE_DEG)
    assert found.targets.tolist() == rows


def test_settles_elsewhere_name_no_mistake():
    plan = targets()
    elsewhere = np.random.default_rng(3).uniform(-150, 150, (5, 6))  # home, a stand-off: no target
    assert convention_mistake(elsewhere, plan, MATCH_DEG) is None


def test_fewer_settles_than_asked_for_name_no_mistake():
    plan, settled = settles_read_with(KUKA_SIGN, KUKA_OFFSET, np.ones(6), KUKA_OFFSET, [4, 7])
    assert convention_mistake(settled, plan, MATCH_DEG, np.ones(6), KUKA_OFFSET) is None
    assert convention_mistake(settled, plan, MATCH_DEG, np.ones(6), KUKA_OFFSET, least=2) is not None


def test_a_joint_that_stood_at_zero_cannot_tell_its_sign():
    plan = targets()
    plan[:, 3] = 0.0  # joint 4 at zero everywhere: its sign changes nothing
    q_true = plan[[2, 8, 20]]
    settled = q_true * np.array([-1, 1, 1, 1, 1, 1])  # joint 1 read flipped
    found = convention_mistake(settled, plan, MATCH_DEG)
    assert found is not None and found.flipped == (0,) and found.untold == (3,)
