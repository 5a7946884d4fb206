"""A setup's ``[cell]``: the next placements the station suggests stay inside the reach box, clear
of the keep-out boxes (the edge and the tool coming onto it), the tool within the tilt allowed."""

import numpy as np
import pytest

import configs
from calib.experiment import line_candidates
from station.formats.tables import SetupCell, load_robot, load_setup
from station.jobs.planning import TOOL_MM, allowed, next_placement, placements, robot_arrays

ROBOT, SETUP = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")
DOWN = [0.0, 0.0, -1.0]
CELL = SetupCell.model_validate(  # in front of the robot (its working side, -x), the tool down
    {"reach": {"min_mm": [-1700, -900, -200], "max_mm": [-500, 900, 1200]}, "max_tilt_from_down_deg": 45}
)


def _cell(**kw) -> SetupCell:
    return SetupCell.model_validate(kw)


def test_a_placement_must_fit_the_reach_box_whole():
    cell = _cell(reach={"min_mm": [-1500, -500, 0], "max_mm": [-500, 500, 1000]})
    assert allowed(cell, [-1000, 0, 500], [0, 1, 0], 400.0, DOWN)
    assert not allowed(cell, [-1000, 0, 500], [0, 1, 0], 1200.0, DOWN)  # its ends stick out
    assert not allowed(cell, [-1000, 400, 500], [0, 1, 0], 400.0, DOWN)


def test_the_edge_and_the_tool_coming_onto_it_keep_out():
    box = {"min_mm": [-1100, -50, 560], "max_mm": [-900, 50, 700]}  # above the edge's centre
    cell = _cell(keep_out=[box])
    assert not allowed(cell, [-1000, 0, 500], [0, 1, 0], 400.0, DOWN)  # the tool comes down through it
    assert allowed(cell, [-1000, 0, 500], [0, 1, 0], 400.0, [0, 0, 1])  # from below it stays clear
    far = 500 + TOOL_MM + 1  # beyond the tool's length
    beyond = _cell(keep_out=[{**box, "min_mm": [-1100, -50, far]}])
    assert allowed(beyond, [-1000, 0, 500], [0, 1, 0], 400.0, DOWN)


def test_the_tool_tilt_from_straight_down():
    cell = _cell(max_tilt_from_down_deg=30.0)
    assert allowed(cell, [-1000, 0, 500], [0, 1, 0], 400.0, DOWN)
    tilted = [np.sin(np.radians(40)), 0.0, -np.cos(np.radians(40))]
    assert not allowed(cell, [-1000, 0, 500], [0, 1, 0], 400.0, tilted)
    assert not allowed(cell, [-1000, 0, 500], [0, 1, 0], 400.0, [0, 0, 1])  # from below


def test_a_box_with_its_corners_reversed_is_refused(tmp_path):
    bad = tmp_path / "setup.toml"
    bad.write_text(SETUP.read_text() + "\n[cell.reach]\nmin_mm = [0, 0, 0]\nmax_mm = [1, -1, 1]\n")
    with pytest.raises(Exception, match="cell.reach: .*min_mm \\[0.0, 0.0, 0.0\\] must lie below max_mm"):
        load_setup(bad)


def test_the_suggested_next_placement_respects_the_cell():
    robot = load_robot(ROBOT)
    dh, tool = robot_arrays(robot)
    limits = np.radians(robot.limits_deg())
    rng = np.random.default_rng(0)
    setup = load_setup(SETUP)
    line = placements(setup, "setup")[0]
    q, ok = line_candidates(dh, tool, limits, line, 40, rng)
    q_deg, ids = np.degrees(q[ok]), np.zeros(int(ok.sum()), int)
    free = next_placement(robot, setup, q_deg, ids)
    assert free is not None and not allowed(CELL, free.point_mm, free.direction, 400.0, free.approach)
    bounded = next_placement(robot, setup.model_copy(update={"cell": CELL}), q_deg, ids)
    assert bounded is not None
    assert allowed(CELL, bounded.point_mm, bounded.direction, 400.0, bounded.approach)
