"""``calib.near``: gauge-line contacts near a program's poses, by the residual map's own distance."""

import numpy as np
import pytest

import configs
from calib import ik
from calib.near import MAX_TILT_DEG, choose, chord_deg, covered, line_contacts, spread, toward_cone, turned
from calib.params import dh_from_degrees
from sim_fixtures.world import Robot, World

ROBOT = Robot.from_file(configs.path("robots/hsr_jr680.toml"))


def test_chord_distance_is_that_of_joints_1_to_3():
    rng = np.random.default_rng(0)
    q, program = rng.uniform(-np.pi, np.pi, (50, 6)), rng.uniform(-np.pi, np.pi, (7, 6))
    chord = 2.0 * np.sin((q[:, None, :3] - program[None, :, :3]) / 2.0)
    expected = np.degrees(np.sqrt(np.sum(chord**2, axis=2)).min(axis=1))
    assert np.allclose(chord_deg(q, program), expected)
    wrist = q.copy()
    wrist[:, 3:] += 1.0  # the wrist is not the map's
    assert np.allclose(chord_deg(wrist, program), expected)
    near = program.copy()
    near[:, 1] += np.radians(4.0)
    assert np.all(covered(near, program, 4.01)) and not np.any(covered(near, program, 3.99))


def test_the_tool_turns_the_least_into_the_cone():
    axis = np.array([0.0, 0.0, -1.0])
    rng = np.random.default_rng(1)
    z = rng.normal(size=(200, 3))
    z /= np.linalg.norm(z, axis=1)[:, None]
    inside = np.degrees(np.arccos(z @ axis)) <= MAX_TILT_DEG
    found = toward_cone(z, axis, MAX_TILT_DEG)
    tilt = np.degrees(np.arccos(np.clip(found @ axis, -1, 1)))
    assert np.allclose(found[inside], z[inside])
    assert np.allclose(tilt[~inside], MAX_TILT_DEG)
    # on the edge, in the plane of the axis and the given direction
    assert np.allclose(np.einsum("ij,ij->i", np.cross(z[~inside], axis), found[~inside]), 0.0, atol=1e-12)
    rotation = np.linalg.qr(rng.normal(size=(200, 3, 3)))[0]
    rotation *= np.linalg.det(rotation)[:, None, None]  # proper rotations
    out = turned(rotation, found)
    assert np.allclose(out[:, :, 2], found)
    assert np.allclose(out @ out.transpose(0, 2, 1), np.eye(3))
    axis_of_turn = np.cross(rotation[:, :, 2], found)  # the least turn keeps what lies along its axis
    assert np.allclose(np.einsum("nij,nj->ni", out @ rotation.transpose(0, 2, 1), axis_of_turn), axis_of_turn)


@pytest.fixture(scope="module")
def contacts():
    world = World.create(0)
    line = world.lines[0]
    program, _ = world.line_configurations(6, np.random.default_rng(3))
    program = np.radians(program[:6] + np.array([2.0, -2.0, 2.0, 5.0, 0.0, 0.0]))
    dh, limits = dh_from_degrees(ROBOT.table_deg), np.radians(ROBOT.limits_deg)
    geometry = (line.centre, line.direction, line.length_mm, line.approach)
    q, ok = line_contacts(dh, ROBOT.tool, limits, geometry, program, np.random.default_rng(4))
    return dh, geometry, program, q, ok


def test_contacts_touch_the_line_near_the_program(contacts):
    dh, (point, direction, length, approach), program, q, ok = contacts
    assert ok.mean() > 0.9
    p, rotation = ik.tool_frames(dh, q[ok], ROBOT.tool)
    rel = p - point
    assert np.linalg.norm(rel - (rel @ direction)[:, None] * direction, axis=1).max() < 1e-3
    assert np.abs(rel @ direction).max() <= length / 2 + 1e-3
    assert np.degrees(np.arccos(rotation[:, :, 2] @ approach)).max() <= MAX_TILT_DEG + 1e-6
    # programs 2 deg off contacts on the line: the nearest tries come back within a few degrees
    first = np.flatnonzero(ok)[np.flatnonzero(ok) % 4 == 0]
    assert np.median(chord_deg(q[first], program)) < 6.0


def test_spread_takes_every_cluster():
    rng = np.random.default_rng(2)
    a = rng.normal(0, 0.01, (30, 6))
    b = rng.normal(0, 0.01, (5, 6)) + np.array([0.5, 0.5, 0.5, 0, 0, 0])
    chosen = spread(np.vstack([a, b]), 2)
    assert len(chosen) == 2 and chosen[0] < 30 <= chosen[1]
    assert np.array_equal(spread(a, 40), np.arange(30))


def test_choose_covers_every_program_pose_a_contact_is_near_first():
    rng = np.random.default_rng(6)
    program = rng.uniform(-1, 1, (40, 6))
    q = np.vstack([rng.normal(0, 0.5, (200, 6)), program[:10] + np.radians(2.0)])  # 10 certainly near
    reachable = covered(q, program)
    chosen = choose(q, program, int(reachable.sum()))
    assert np.array_equal(covered(q[chosen], program), reachable)
    assert len(chosen) == len(np.unique(chosen)) == reachable.sum()
