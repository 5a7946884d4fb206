"""Your own cell rehearsed (``station sim serve --robot R --setup S``): the simulator's truth is
drawn around the user's robot file and setup, and its robot program walks the plan's nominal joints,
so the tool lands off the edge by the robot's error, as on a real robot."""

import numpy as np
import pytest
import tomli_w

import configs
from errors import InputError
from sim_fixtures.world import TOLERANCES
from station.commands.sim import rehearsed_cell
from station.formats.tables import load_robot, load_setup

UR10_SETUP = {
    "drawstring": {"anchor_mm": [600.0, -600.0, -400.0], "length_offset_mm": 200.0},
    "lines": [
        {
            "id": 0,
            "point_mm": [700.0, 0.0, 100.0],
            "direction": [0, 1, 0],
            "length_mm": 400.0,
            "dial_axis": [0, 0, 1],
            "approach": [0, 0, -1],
        },
        {
            "id": 1,
            "point_mm": [500.0, 500.0, 300.0],
            "direction": [1, 0, 0],
            "length_mm": 300.0,
            "dial_axis": [0, 0, 1],
            "approach": [0, 0, -1],
        },
    ],
}


def _setup(tmp_path, content=UR10_SETUP):
    path = tmp_path / "setup.toml"
    path.write_text(tomli_w.dumps(content))
    return load_setup(path)


@pytest.fixture(scope="module")
def ur10():
    return load_robot(configs.path("robots/ur10.toml"))


def _nominal_plan(robot, setup, n=10):
    """The nominal model's contacts along the setup's lines (as ``station plan`` would choose)."""
    from sim_fixtures.world import Robot, World
    from station.commands.sim import placement

    cell = placement(setup, "setup.toml")
    nominal = Robot(robot.table_deg(), np.zeros(3), robot.limits_deg())
    drawn = World(nominal, nominal, cell.anchor_mm, cell.length_offset_mm, cell.lines)
    return drawn.line_configurations(n, np.random.default_rng(0))


def test_the_rehearsed_robot_misses_the_edge_by_its_own_error(tmp_path, ur10):
    setup = _setup(tmp_path)
    q_plan, lines = _nominal_plan(ur10, setup)
    cell = rehearsed_cell(ur10, setup, "setup.toml", seed=3, plan=(q_plan, lines), targets_per_line=10)
    world = cell.world
    np.testing.assert_array_equal(world.nominal.table_deg, ur10.table_deg())  # the user's robot
    error = world.true.table_deg - world.nominal.table_deg
    # 12 angles and 12 lengths drawn at the stated tolerance: their RMS within a factor 2 of it
    assert TOLERANCES.angle_deg / 2 < np.sqrt(np.mean(error[:, [0, 3]] ** 2)) < 2 * TOLERANCES.angle_deg
    assert TOLERANCES.length_mm / 2 < np.sqrt(np.mean(error[:, [1, 2]] ** 2)) < 2 * TOLERANCES.length_mm
    assert len(cell.plan_deg) == len(q_plan)  # every commanded contact lands
    # the commanded joints put the TRUE tool mm away from the nominal contact ...
    miss = world.true.tcp(q_plan) - world.nominal.tcp(q_plan)
    assert np.median(np.linalg.norm(miss, axis=1)) > 1.0
    # ... the edge guides it across, the dial reads what the robot misses along its axis
    true_lines = {ln.id: ln for ln in world.lines}
    for q_cmd, q_true, lid in zip(q_plan, cell.plan_deg, cell.plan_lines, strict=True):
        ln = true_lines[lid]
        rel = world.true.tcp(q_true) - ln.centre
        across = np.cross(ln.direction, ln.dial_axis)
        assert abs(rel @ across) < 1e-3
        assert rel @ ln.dial_axis == pytest.approx(
            (world.true.tcp(q_cmd) - ln.centre) @ ln.dial_axis, abs=1e-3
        )
        assert np.abs(q_true - q_cmd).max() < 1.0  # deg: the joints stay where commanded, nearly
    dial = cell.true_dial_mm(cell.plan_deg, cell.plan_lines)
    assert np.abs(dial).max() > 2.0  # beyond the shipped +-2 mm dial gate somewhere
    again = rehearsed_cell(ur10, setup, "setup.toml", seed=3, plan=(q_plan, lines), targets_per_line=10)
    np.testing.assert_array_equal(again.world.true.table_deg, world.true.table_deg)


def test_a_plan_on_a_line_the_setup_lacks_is_refused(tmp_path, ur10):
    q = np.array([[0.0, -90.0, 90.0, -90.0, -90.0, 0.0]] * 2)
    with pytest.raises(InputError, match=r"^--plan: line 7 is not among setup.toml's \[\[lines\]\]"):
        rehearsed_cell(ur10, _setup(tmp_path), "setup.toml", 0, (q, np.array([0, 7])), 10)
    cell = rehearsed_cell(ur10, _setup(tmp_path), "setup.toml", 0, None, 5)  # no plan: the nominal contacts
    assert sorted(set(cell.plan_lines.tolist())) == [0, 1] and len(cell.plan_deg) == 10


def test_a_setup_without_what_the_simulator_needs_is_one_line_naming_it(tmp_path, ur10):
    no_point = {**UR10_SETUP, "lines": [{"id": 0, "direction": [0, 1, 0], "dial_axis": [0, 0, 1]}]}
    with pytest.raises(InputError, match=r"^s.toml: \[\[lines\]\] id 0: missing point_mm or direction"):
        rehearsed_cell(ur10, _setup(tmp_path, no_point), "s.toml", 0, None, 10)
    no_drawstring = {"lines": UR10_SETUP["lines"]}
    with pytest.raises(InputError, match=r"^s.toml: missing table \[drawstring\]"):
        rehearsed_cell(ur10, _setup(tmp_path, no_drawstring), "s.toml", 0, None, 10)
    far = {**UR10_SETUP, "lines": [{**UR10_SETUP["lines"][0], "point_mm": [5000.0, 0.0, 0.0]}]}
    with pytest.raises(InputError, match=r"^s.toml: gauge line 0 is out of the robot's reach"):
        rehearsed_cell(ur10, _setup(tmp_path, far), "s.toml", 0, None, 10)
