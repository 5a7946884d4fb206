"""A simulated cell carrying an unmodelled error (``[sim] unmodelled``): its true TCP carries the
error in every reading, its plan still touches the lines, its joints read as ever."""

import dataclasses

import numpy as np
import pytest

import configs
from errors import InputError
from sim_fixtures.station_sim import SimStation, make_cell
from sim_fixtures.unmodelled import UR10_LIKE
from sim_fixtures.world import World
from station.config import station_config
from station.formats.base import read_toml


@pytest.fixture(scope="module")
def cells():
    return make_cell(0, 8), make_cell(0, 8, UR10_LIKE)


def test_the_true_tcp_carries_the_unmodelled_error():
    plain = World.create(3)
    world = dataclasses.replace(plain, unmodelled=UR10_LIKE)
    q = plain.random_configurations(500, np.random.default_rng(0))
    shift = world.true_tcp_mm(q) - plain.true_tcp_mm(q)
    expected = UR10_LIKE.tcp_mm(plain.true.dh, np.radians(q), plain.true.tool) - plain.true.tcp(q)
    assert np.allclose(shift, expected, atol=1e-9)
    assert 0.1 < np.sqrt(np.mean(np.sum(shift**2, axis=1))) < 2.0  # tenths of a mm: a map's size
    assert np.allclose(world.true_tcp_mm(q[0]), world.true_tcp_mm(q[:1])[0])
    length = np.linalg.norm(world.true_tcp_mm(q) - world.anchor_mm, axis=1) - world.length_offset_mm
    assert np.allclose(world.true_length_mm(q), length)


def test_its_plan_touches_the_lines_the_dial_reading_the_placement(cells):
    plain, cell = cells
    world = cell.world
    assert world.unmodelled is UR10_LIKE and plain.world.unmodelled is None
    by_id = {ln.id: ln for ln in world.lines}
    for q, lid in zip(cell.plan_deg, cell.plan_lines, strict=True):
        ln = by_id[int(lid)]
        rel = world.true_tcp_mm(q) - ln.centre
        across = rel - (rel @ ln.direction) * ln.direction - (rel @ ln.dial_axis) * ln.dial_axis
        assert np.linalg.norm(across) < 1e-6  # on the edge but for the dial axis
    dial = cell.true_dial_mm(cell.plan_deg, cell.plan_lines)
    assert np.all(np.abs(dial) <= world.noise.placement_mm + 1e-9)
    # the table's TCP misses the edge by the unmodelled error: what the truth carries
    miss = world.true_tcp_mm(cell.plan_deg) - world.true.tcp(cell.plan_deg)
    assert np.sqrt(np.mean(np.sum(miss**2, axis=1))) > 0.05


def test_a_landed_program_touches_the_true_line(cells):
    _, cell = cells
    q, lines = cell.world.land(cell.plan_deg + 0.3, cell.plan_lines)
    world, by_id = cell.world, {ln.id: ln for ln in cell.world.lines}
    rel = world.true_tcp_mm(q) - np.array([by_id[int(k)].centre for k in lines])
    dirs = np.array([by_id[int(k)].direction for k in lines])
    dials = np.array([by_id[int(k)].dial_axis for k in lines])
    across = rel - np.sum(rel * dirs, 1)[:, None] * dirs - np.sum(rel * dials, 1)[:, None] * dials
    assert len(q) == len(cell.plan_deg) and np.abs(across).max() < 1e-6


def test_the_station_config_names_the_kind():
    raw = read_toml(configs.path("station.toml"))
    assert station_config(raw, "s.toml").sim.unmodelled == "none"
    raw["sim"]["unmodelled"] = "ur10-like"
    assert station_config(raw, "s.toml").sim.unmodelled == "ur10-like"
    raw["sim"]["unmodelled"] = "ur5"
    with pytest.raises(InputError, match=r"^s.toml: sim.unmodelled: .*'none' or 'ur10-like'$"):
        station_config(raw, "s.toml")


def test_sim_serve_s_cell_carries_it_in_its_readings():
    raw = read_toml(configs.path("station.toml"))
    raw["sim"].update(unmodelled="ur10-like", targets_per_line=8)
    station = SimStation(station_config(raw, "s.toml"))
    world, state = station.source.cell.world, station.source.state(0.0)  # still at the first target
    assert world.unmodelled is UR10_LIKE
    assert state.length_mm == pytest.approx(world.true_length_mm(np.array(state.q_deg))[0])
    assert np.array_equal(station.plan_deg, make_cell(0, 8, UR10_LIKE).plan_deg)
