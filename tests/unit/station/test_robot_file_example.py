"""The shipped commented robot file (issue 35, item 9): it loads, it is the JR680 written in Craig's
modified D-H, and it names every key the robot file takes, so a key added without documentation
fails here."""

import re

import numpy as np
import pytest

import configs
from station.formats.tables import Controller, Flange, Joint, Payload, RobotFile, load_robot

EXAMPLE = configs.path("robots/example_commented.toml")


def test_the_commented_example_loads_as_the_jr680_in_modified_dh():
    example = load_robot(EXAMPLE)
    assert example.convention == "mdh"
    jr680 = load_robot(configs.path("robots/hsr_jr680.toml"))
    np.testing.assert_allclose(example.table_deg(), jr680.table_deg())
    np.testing.assert_allclose(example.limits_deg(), jr680.limits_deg())


@pytest.mark.parametrize("model", [RobotFile, Joint, Payload, Flange, Controller], ids=lambda m: m.__name__)
def test_the_commented_example_shows_every_key_of_the_robot_file(model):
    """Each key as a line of its own, set or commented out (``# serial = ...``, ``# [payload]``)."""
    text = EXAMPLE.read_text()
    missing = [
        key
        for key in model.model_fields
        if not re.search(rf"^(?:# ?)?(?:{key} = |\[\[?{key}\]\]?$)", text, re.MULTILINE)
    ]
    assert not missing, f"{EXAMPLE.name} does not show {missing}"


def test_the_commented_example_explains_the_controllers_joint_convention():
    text = EXAMPLE.read_text()
    assert "q_model = joint_sign * reading + joint_offset_deg" in text
    assert "joint_sign = [-1, 1, 1, -1, 1, -1]" in text  # KUKA's A1, A4, A6
