"""Issue 36's done-when, at reduced size (``benchmarks/residual_map_sim.py`` at full): a cell
measured on a ``station plan --near`` plan of a program, calibrated, checked at the program's
poses against the simulated truth."""

import pytest

from benchmarks import residual_map_sim as sim
from sim_fixtures.world import World

NOISE_MM = World.create(0).noise.length_mm


@pytest.fixture(scope="module")
def plan_and_program():
    program = sim.program_deg(30)
    return sim.near_plan(program, 30), program


@pytest.fixture(scope="module")
def cells(plan_and_program):
    plan, program = plan_and_program
    kinds = ("tracker", "ideal", "drawstring")
    return {u: sim.one_cell(1, sim.UR10_LIKE if u else None, plan, program, kinds) for u in (True, False)}


def test_the_plan_reaches_every_program_pose(cells):
    assert all(c["near_poses"] == 30 for c in cells.values())


def test_a_cell_without_the_error_meets_the_program_with_the_table_alone(cells):
    # nothing unmodelled: the table alone puts the program within twice the drawstring's noise
    assert cells[False]["tracker"]["table_rmse_mm"] <= 2 * NOISE_MM


def test_the_unmodelled_error_is_what_the_table_leaves_and_a_tracker_map_takes_much_of_it(cells):
    c = cells[True]["tracker"]
    assert c["table_rmse_mm"] > 5 * NOISE_MM  # the truth carries it: no table expresses it
    assert c["on"] and c["map_rmse_mm"] < 0.5 * c["table_rmse_mm"]
    # 30 poses inside a 95 % bound: 27 or more unless the bound is too tight (binomial, p < 2 %)
    assert c["inside_95"] >= 0.9


def test_where_the_table_is_right_the_near_plan_s_map_meets_the_program_within_twice_the_noise(cells):
    # the unmodelled error alone, seen by a tracker at the plan's poses: the plan covers the
    # program densely enough for the map to take it to the instruments' level
    c = cells[True]["ideal"]
    assert c["on"] and c["table_rmse_mm"] > 5 * NOISE_MM
    assert c["map_rmse_mm"] <= 2 * NOISE_MM and c["inside_95"] >= 0.9


def test_the_calibrations_own_rows_keep_the_map_off_without_the_error(cells):
    assert not cells[False]["drawstring"]["on"]


def test_the_calibrations_own_rows_undo_what_the_table_took_of_the_error(cells):
    # the table alone is further off at the program's poses than the error itself (its geometry
    # took part of the cyclic error); the angle errors fitted beside it take most of that back,
    # and 27 or more of the 30 poses lie inside the 95 % bound (binomial, p < 2 %)
    c = cells[True]["drawstring"]
    assert c["on"] and c["table_rmse_mm"] > 10 * NOISE_MM
    assert c["map_rmse_mm"] < 0.25 * c["table_rmse_mm"] and c["inside_95"] >= 0.9
