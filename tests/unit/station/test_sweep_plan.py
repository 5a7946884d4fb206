"""``station plan --sweep``: passes along every gauge line that ``station sample`` and ``station
program`` read, and a promise checked against the simulated world measured along the passes."""

import json

import numpy as np
import pytest
import tomli_w

import configs
from calib import ik
from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from calib.params import dh_from_degrees
from calib.sweep import swept_rows
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import Noise, World
from station import cli
from station.formats.base import read_toml
from station.formats.plan import load_plan
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot, load_setup
from station.jobs import calibration, sweeping
from station.jobs.sweeping import SWEEP

ROBOT, SETUP = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep")
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--sweep", "--out", str(out / "plan.csv")]
    assert cli.main(argv + ["--report", str(out / "plan.json")]) == 0
    return load_plan(out / "plan.csv"), json.loads((out / "plan.json").read_text())


def test_each_line_gets_a_pass_from_one_end_of_its_edge_to_the_other(swept):
    plan, report = swept
    assert plan.is_sweep
    robot = load_robot(ROBOT)
    dh = dh_from_degrees(robot.table_deg())
    p = tcp_position(dh, np.radians(plan.q_deg), np.asarray(robot.tool_mm, float))
    lines = {ln.id: ln for ln in load_setup(SETUP).lines}
    assert sorted(int(plan.line[idx[0]]) for idx in plan.passes()) == sorted(lines)
    for idx in plan.passes():
        ln = lines[int(plan.line[idx[0]])]
        direction = np.array(ln.direction) / np.linalg.norm(ln.direction)
        along = (p[idx] - ln.point_mm) @ direction
        assert np.abs(np.cross(p[idx] - ln.point_mm, direction)).max() < 1e-3
        assert np.all(np.diff(along) * np.sign(along[-1] - along[0]) > 0)  # in order along the edge
        assert abs(along[-1] - along[0]) == pytest.approx(ln.length_mm, abs=1e-3)
    assert report["swept_s"] == pytest.approx(sum(q["duration_s"] for q in report["passes"]))
    assert report["swept_s"] <= 120.0


def test_the_sweep_delivers_its_promise_on_the_simulated_world(swept):
    # Sweep the passes in three true cells (rows at the stated rate along the linear moves, the
    # tool moved onto each true line, one reading per row), calibrate, compare with the truth: below
    # the 95 % bound each time and the RMS over the cells below the expected value. One-sided: the
    # promise is from the setup's stated noise, whose line term (line_sigma_mm 0.01, how well the
    # tool sits on the edge) is five times the simulated dial's 0.002 mm, and thousands of swept
    # rows let that term weigh (the static plan's test, with few rows, holds the promise within
    # 2x both ways). The cells' joints read exactly, as the simulated controller's: the setup states
    # no joint noise (the world's 0.0005 deg, some 0.01 mm at the TCP a joint, would be what is
    # left once thousands of rows average the instruments').
    plan, report = swept
    robot, promise = load_robot(ROBOT), report["predicted"]["plan"]
    dh, tool = dh_from_degrees(robot.table_deg()), np.asarray(robot.tool_mm, float)
    limits = np.radians(robot.limits_deg())
    rows = [swept_rows(dh, tool, limits, np.radians(plan.q_deg[idx]), SWEEP) for idx in plan.passes()]
    q_plan = np.degrees(np.concatenate([r.q for r in rows]))
    line = np.concatenate(
        [np.full(len(r.q), plan.line[idx[0]]) for r, idx in zip(rows, plan.passes(), strict=True)]
    )
    true = []
    for seed in (1, 2, 3):
        world = World.create(seed, n_lines=3, noise=Noise(q_deg=0.0))
        rng = np.random.default_rng(seed + 1000)
        q_true, ids = world.touch_lines(q_plan, line, rng)
        assert len(ids) >= 0.95 * len(line)
        s = world.measure(q_true, ids, rng)
        samples = Samples("sweep", "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line)
        out = calibration.calibrate_samples(samples, robot, SetupFile.model_validate(setup_dict(world, rng)))
        q = world.random_configurations(1000, np.random.default_rng(99))
        p = tcp_position(dh_table(out.calibration.x), np.radians(q), np.zeros(3))
        true.append(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))
    assert max(true) < promise["predicted_rmse_95_mm"]
    assert np.sqrt(np.mean(np.square(true))) < promise["predicted_rmse_mm"]


def test_a_line_no_pass_can_sweep_is_a_one_line_error(tmp_path, capsys):
    data = read_toml(SETUP)
    data["lines"][1]["point_mm"] = [-4000.0, 0.0, 150.0]
    setup = tmp_path / "setup.toml"
    setup.write_text(tomli_w.dumps(data))
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(setup), "--sweep", "--out", str(tmp_path / "p.csv")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "[[lines]] id 1: 0 of 1 passes" in err
    assert not (tmp_path / "p.csv").exists()


def test_extra_passes_go_where_they_promise_most_and_never_twice_in_a_row_on_a_line(swept):
    plan, report = swept
    design = sweeping.sweep_design(load_robot(ROBOT), load_setup(SETUP), str(SETUP), passes=1, extra=2)
    lines = [int(design.plan.line[idx[0]]) for idx in design.plan.passes()]
    assert len(lines) == 5 and all(a != b for a, b in zip(lines, lines[1:], strict=False))
    one_each = {int(plan.line[idx[0]]): plan.q_deg[idx] for idx in plan.passes()}
    kept = [design.plan.q_deg[idx] for idx in design.plan.passes()]
    for lid, q in one_each.items():  # the first round is the plan of one pass a line, unchanged
        assert any(w.shape == q.shape and np.allclose(w, q) for w in kept), lid
    promised = design.report["predicted"]["plan"]["predicted_rmse_mm"]
    assert promised < report["predicted"]["plan"]["predicted_rmse_mm"]


def test_alternating_keeps_round_robin_order_and_splits_a_line_with_most_passes():
    chosen = [(0, "a"), (1, "b"), (2, "c"), (0, "d"), (0, "e"), (1, "f")]
    assert [c[1] for c in sweeping.alternating(chosen[:3])] == ["a", "b", "c"]
    order = sweeping.alternating(chosen)
    assert sorted(order) == sorted(chosen)
    assert all(a[0] != b[0] for a, b in zip(order, order[1:], strict=False))
    assert [c[1] for c in order if c[0] == 0] == ["a", "d", "e"]


@pytest.mark.parametrize("flag", ["--extra-passes", "--max-tilt"])
def test_a_sweeps_options_without_sweep_are_a_one_line_error(tmp_path, capsys, flag):
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), flag, "2"]
    assert cli.main(argv + ["--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{flag}: only with --sweep" in err
    assert not (tmp_path / "p.csv").exists()


def _tilts_deg(plan) -> np.ndarray:
    """Each waypoint's tool axis from its line's approach [deg] (the tool's z, the robot's table)."""
    robot = load_robot(ROBOT)
    dh = dh_from_degrees(robot.table_deg())
    z = ik.tool_frames(dh, np.radians(plan.q_deg), np.asarray(robot.tool_mm, float))[1][:, :, 2]
    return np.degrees(np.arccos(np.clip(np.sum(z * plan.approach, axis=1), -1.0, 1.0)))


def test_max_tilt_bounds_every_waypoints_tool_and_is_reported(swept, tmp_path, capsys):
    # a tool that cannot lean 45 deg on the edge: the plan keeps to what it is told, and says so
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--sweep", "--max-tilt", "10"]
    out = tmp_path / "plan.csv"
    assert cli.main(argv + ["--max-roll", "30", "--out", str(out), "--report", str(tmp_path / "r.json")]) == 0
    assert "tilted up to 10 deg and rolled up to 30 deg" in capsys.readouterr().out
    limits = json.loads((tmp_path / "r.json").read_text())["limits"]
    assert (limits["max_tilt_deg"], limits["max_roll_deg"]) == (10.0, 30.0)
    assert _tilts_deg(load_plan(out)).max() <= 10.0 + 1e-6
    assert _tilts_deg(swept[0]).max() > 10.0  # the default leans further
    assert swept[1]["limits"]["max_tilt_deg"] == sweeping.SHAPE.max_tilt_deg


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--max-tilt", "90"], "argument --max-tilt: 90.0 must be from 0 to below 90 deg"),
        (["--max-roll", "-5"], "argument --max-roll: -5.0 must be from 0 to 180 deg"),
        (["--max-roll", "wide"], "argument --max-roll: 'wide' is not a number of degrees"),
    ],
)
def test_turns_a_tool_cannot_take_are_refused_by_the_parser(tmp_path, capsys, extra, said):
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--sweep", *extra]
    with pytest.raises(SystemExit) as done:
        cli.main(argv + ["--out", str(tmp_path / "p.csv")])
    assert done.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(said)
    assert not (tmp_path / "p.csv").exists()


def test_a_tool_that_cannot_tilt_is_told_which_line_it_cannot_sweep_and_why(tmp_path, capsys):
    # with the tool held at its line's approach, line 1's pass runs through the wrist's singularity
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--sweep", "--max-tilt", "0"]
    assert cli.main(argv + ["--out", str(tmp_path / "p.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "[[lines]] id 1: 0 of 1 passes" in err and "let the tool tilt more than 0 deg" in err
    assert not (tmp_path / "p.csv").exists()
