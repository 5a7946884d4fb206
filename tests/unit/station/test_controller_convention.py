"""The controller's joint convention in the station: ``[sim] joint_sign`` / ``joint_offset_deg``
override the rehearsed robot file's ``[controller]``; a session's settles away from every target
are named as a convention mistake once, with the fix."""

import numpy as np
import pytest

from errors import InputError
from station.acquire.convention import AwaySettles
from station.config import load_station_config
from station.formats.tables import Controller

BASE = """
[robot]
kind = "rtde"
[drawstring]
kind = "modbus_tcp"
"""
KUKA = Controller(joint_sign=[-1, 1, 1, -1, 1, -1], joint_offset_deg=[0, -90, 90, 0, 0, 0])
MATCH_DEG = 2.0


def config(tmp_path, sim: str = ""):
    path = tmp_path / "station.toml"
    path.write_text(BASE + "[sim]\n" + sim)
    return load_station_config(path)


def test_the_simulated_controller_follows_the_robot_file_unless_sim_says_otherwise(tmp_path):
    assert config(tmp_path).sim.convention(None) == ([1.0] * 6, [0.0] * 6)
    sign, offset = config(tmp_path).sim.convention(KUKA)
    assert sign == [-1, 1, 1, -1, 1, -1] and offset == [0, -90, 90, 0, 0, 0]
    mistaken = config(tmp_path, "joint_sign = [1, 1, 1, 1, 1, 1]\n").sim.convention(KUKA)
    assert mistaken == ([1.0] * 6, [0.0, -90.0, 90.0, 0.0, 0.0, 0.0])  # the signs rehearsed wrong


@pytest.mark.parametrize(
    "sim, says",
    [
        ("joint_sign = [1, 1, 2, 1, 1, 1]\n", r"station.toml: sim.joint_sign.2: Input should be 1 or -1"),
        (
            "joint_offset_deg = [0, 0, 0]\n",
            r"station.toml: sim.joint_offset_deg: 3 values: give 6, joint 1 first \(or \[\] for the",
        ),
    ],
)
def test_a_bad_simulated_convention_is_one_line_naming_the_key(tmp_path, sim, says):
    with pytest.raises(InputError, match=says):
        config(tmp_path, sim)


def _plan(n=30, seed=0):
    return np.random.default_rng(seed).uniform(-150, 150, (n, 6)), np.arange(100, 100 + n)


def test_settles_away_from_every_target_name_the_flipped_signs_once(tmp_path):
    plan, ids = _plan()
    away = AwaySettles(plan, ids, MATCH_DEG, Controller(), "cell/robot.toml")
    read = plan[[3, 7, 11, 12]] * KUKA.joint_sign  # a controller turning A1, A4, A6 the other way
    said = [away.settled(q) for q in (read[0], read[0] + 0.5, read[1], read[2], read[3])]
    assert said[:3] == [None, None, None]  # the same place twice is one settle: two so far
    assert said[3] == (
        "the robot settled 3 times away from every target; with joint 1's, 4's and 6's signs flipped, 3 of "
        "them lie at targets 103, 107, 111: set [controller] joint_sign = [-1, 1, 1, -1, 1, -1] in "
        "cell/robot.toml"
    )
    assert said[4] is None and away.advice == said[3]  # said once; the ending repeats away.advice


def test_a_joint_zero_off_by_a_half_turn_is_named_with_the_offset(tmp_path):
    plan, ids = _plan()
    file_offset = np.array(KUKA.joint_offset_deg) + [0, 0, 0, 0, 0, 180]  # joint 6's zero off
    wrong = Controller(joint_sign=KUKA.joint_sign, joint_offset_deg=file_offset.tolist())
    away = AwaySettles(plan, ids, MATCH_DEG, wrong, "robot.toml")
    reading = KUKA.controller_deg(plan[[0, 1, 2]])
    said = [away.settled(q) for q in wrong.model_deg(reading)]
    assert said[2] == (
        "the robot settled 3 times away from every target; with joint 6's zero moved by -180 deg, 3 of "
        "them lie at targets 100, 101, 102: set [controller] joint_offset_deg = [0, -90, 90, 0, 0, 0] in "
        "robot.toml"
    )
