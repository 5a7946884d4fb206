"""Corrected targets during a session: the running calibration's model, registered to the cell by the
lines it fitted, brings the tool of the simulated true robot onto an edge the planned joints miss
(``station.jobs.correction``), and the session hands them to the program in order, once each,
through the robot's target channel (``station.acquire.targets``)."""

import numpy as np
import pytest

import configs
from drivers.base import DeviceUnreachable
from station.acquire.targets import TargetFeed
from station.commands.sim import rehearsed_cell
from station.formats.plan import Plan
from station.formats.tables import load_robot, load_setup
from station.jobs.correction import TargetCorrection, correct_targets
from station.jobs.running import SessionSamples, refit

GATE_MM = 2.0


@pytest.fixture(scope="module")
def irb_cell():
    """The rehearsed IRB 2600 of seed 14 on the shipped setup: its planned contacts along each line
    (the nominal model's), the world behind them."""
    robot = load_robot(configs.path("robots/abb_irb2600.toml"))
    setup = load_setup(configs.path("setups/irb2600.toml"))
    cell = rehearsed_cell(robot, setup, "setup.toml", 14, None, 20)
    return robot, setup, cell.world, _nominal_plan(cell.world, robot, setup)


def _nominal_plan(world, robot, setup):
    from sim_fixtures.world import World
    from station.commands.sim import nominal_robot, placement

    cell = placement(setup, "setup.toml")
    nominal = nominal_robot(robot)
    drawn = World(nominal, nominal, cell.anchor_mm, cell.length_offset_mm, cell.lines)
    return drawn.line_configurations(20, np.random.default_rng(2))


def test_the_refits_model_brings_the_tool_onto_an_edge_the_plan_misses(irb_cell):
    robot, setup, world, (q_plan, lines) = irb_cell
    q_true, reached = world.landing(q_plan, lines)
    miss = world.true_dial_mm(q_true, lines)
    third = lines == 2
    assert reached.all() and np.sqrt(np.mean(miss[third] ** 2)) > GATE_MM  # the plan misses its edge
    first_two = ~third
    measured = world.measure(q_true[first_two], lines[first_two], np.random.default_rng(1), readings=5)
    fit = refit(
        robot, setup, SessionSamples(measured.q_deg, measured.length_mm, measured.dial_mm, measured.line)
    )
    assert fit.judged
    found = correct_targets(robot, setup, fit, q_plan, lines)
    assert found.n == int(first_two.sum()) and found.ok.all()
    q_new, reached = world.landing(found.q_deg, lines)
    landed = world.true_dial_mm(q_new, lines)
    assert reached.all()
    # on the fitted lines the fit's own line is aimed at: the model's error, tenths of a mm
    assert np.abs(landed[first_two]).max() < 0.3, landed[first_two]
    # on the third, the setup's line carried into the model's frame: its placement (0.5 mm per
    # axis, so 1.5 mm at 3 sigma across it) and the model's error there
    assert np.abs(landed[third]).max() < 1.5, landed[third]
    assert np.all(found.shift_mm[third] > np.abs(miss[third]) - 0.5)  # the robot's error there, and more


class Channel:
    """A target channel that records what it is given; ``fail`` makes writes fail."""

    where = "test registers"

    def __init__(self, fail=False):
        self.written, self.fail = [], fail

    def write(self, target, q_deg):
        if self.fail:
            raise DeviceUnreachable("robot", "the controller went away")
        self.written.append((target, list(q_deg)))


def _feed(channel, unfinished, why="no such thing"):
    plan = Plan(np.arange(10, 16), np.zeros(6, int), np.zeros((6, 6)))
    said, noted = [], []
    feed = TargetFeed(plan, lambda: channel, lambda: why, lambda: unfinished, said.append, noted.append)
    q = np.arange(36.0).reshape(6, 6)
    return feed, TargetCorrection(30, q, np.array([1, 1, 0, 1, 1, 1], bool), np.full(6, 1.5)), said, noted


def test_the_next_unfinished_target_goes_to_the_program_once_when_the_robot_settles():
    channel = Channel()
    feed, correction, said, noted = _feed(channel, [1, 2, 4, 5])
    feed.settled(0)
    assert channel.written == []  # nothing corrected yet
    feed.corrected(correction)
    assert channel.written == [(11, list(correction.q_deg[1]))]  # target id 11: plan row 1
    assert said[0].startswith("running calibration: correcting the remaining targets in-session")
    assert "through test registers" in said[0] and said[1].startswith("target 11: corrected target sent")
    feed.settled(0)
    feed.corrected(correction)
    assert len(channel.written) == 1  # once per target
    feed.settled(1)  # row 2 cannot be corrected: it keeps its joints, said in the log
    assert len(channel.written) == 1 and noted[-1].startswith("target 12: not corrected")
    feed.settled(3)  # row 3 finished already: the next unfinished after it
    assert channel.written[-1][0] == 14 and noted[-1].startswith("target 14: corrected target sent")
    assert feed.sent == {11: 30, 12: 0, 14: 30}


def test_before_the_robot_settles_anywhere_the_first_unfinished_target_goes_to_the_program():
    """A resumed session's model is determined before the program starts: the program's first
    target (the plan's first unfinished) is corrected in time."""
    channel = Channel()
    feed, correction, said, _ = _feed(channel, [1, 2, 4, 5])
    assert feed.remedy("station sample --resume s") is None  # nothing corrected yet
    feed.corrected(correction)
    assert channel.written == [(11, list(correction.q_deg[1]))]
    assert feed.remedy("station sample --resume s") == (  # plan row 2 cannot be corrected
        "run the robot program again with station sample --resume s: the model of 30 samples "
        "corrects 3 of the 4 targets left as it reaches them"
    )
    unfixable, _, _, _ = _feed(Channel(), [2])
    unfixable.corrected(correction)
    assert unfixable.remedy("station sample --resume s").startswith(
        "the model of 30 samples cannot correct the 1 target left (station compensate says why, e.g. a "
        "joint limit): widen [session] dial_range_mm"
    )
    left = [1, 2]
    finished, _, _, _ = _feed(Channel(), left)
    finished.corrected(correction)  # target 11 (row 1) sent
    left.remove(1)  # and measured: the robot standing there says nothing of a miss
    finished.settled(1)
    assert finished.remedy("station sample --resume s").startswith(
        "the model of 30 samples cannot correct the 1 target left"
    )
    feed.settled(1)  # the robot stands at target 11, sent corrected: it missed the edge all the same
    assert feed.remedy("station sample --resume s").startswith(
        "target 11's corrected joints missed the edge too (model of 30 samples): calibrate what was "
        "measured (station calibrate) and follow its next step"
    )


def test_a_robot_without_a_channel_is_told_the_offline_route_once_and_a_failed_write_stops_it():
    feed, correction, said, _ = _feed(None, [1, 2], why="a robot connection of this kind has none")
    feed.settled(0)
    feed.corrected(correction)
    feed.corrected(correction)
    assert len(said) == 1
    assert said[0].startswith("targets are not corrected in-session: the robot connection offers no target")
    assert "(a robot connection of this kind has none)" in said[0]
    assert "station program the plan with --table (that table) and --session (this session)" in said[0]
    assert "station sample --resume" in said[0]
    channel = Channel(fail=True)
    feed, correction, said, _ = _feed(channel, [1, 2])
    feed.settled(0)
    feed.corrected(correction)
    assert said[-1] == "robot: the controller went away; targets are no longer corrected in-session"
    assert feed.remedy("station sample --resume s") is None  # the offline route, then
    channel.fail = False
    feed.settled(1)
    assert channel.written == []
