"""``station plan``: candidates the nominal robot reaches on the setup's lines, an MCS plan that
``station sample`` reads, and promises checked against the simulated world."""

import json

import numpy as np
import pytest
import tomli_w

import configs
from calib import ik
from calib.experiment import MIN_CONDITIONING
from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from calib.params import dh_from_degrees
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import World
from station import cli
from station.formats.base import read_toml
from station.formats.plan import load_plan
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot, load_setup
from station.jobs import calibration

ROBOT, SETUP = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan")
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--readings", "1"]
    argv += ["--out", str(out / "plan.csv")]
    assert cli.main(argv + ["--report", str(out / "plan.json"), "--plot", str(out / "plan.png")]) == 0
    return load_plan(out / "plan.csv"), json.loads((out / "plan.json").read_text()), out


def test_plan_targets_touch_their_lines_within_the_limits(planned):
    plan, report, out = planned
    robot = load_robot(ROBOT)
    dh, limits = dh_from_degrees(robot.table_deg()), robot.limits_deg()
    q = np.radians(plan.q_deg)
    p = tcp_position(dh, q, np.zeros(3))
    for ln in load_setup(SETUP).lines:
        on = plan.line == ln.id
        direction = np.array(ln.direction) / np.linalg.norm(ln.direction)
        off = np.linalg.norm(np.cross(p[on] - ln.point_mm, direction), axis=1)
        assert on.sum() >= 4 and off.max() < 1e-3
    assert np.all((plan.q_deg >= limits[:, 0]) & (plan.q_deg <= limits[:, 1]))
    assert ik.conditioning(dh, q, np.zeros(3)).min() > MIN_CONDITIONING
    assert len(plan) == report["selection"]["n"] < sum(report["candidates"].values())
    assert (out / "plan.png").stat().st_size > 10_000


def test_more_lines_promise_more_and_the_suggestion_adds_to_all(planned):
    # Information only adds: a superset of lines never promises worse, nor does a further line.
    _, report, _ = planned
    by_lines = {tuple(p["lines"]): p["predicted_rmse_mm"] for p in report["placements"]}
    everything = by_lines[(0, 1, 2)]
    assert all(everything <= v for v in by_lines.values())
    assert min(by_lines[(0,)], by_lines[(1,)], by_lines[(2,)]) > 2 * everything
    assert report["next"] and report["next"][0]["predicted_rmse_mm"] <= everything
    assert (
        report["predicted"]["all_candidates"]["predicted_rmse_mm"]
        <= report["predicted"]["plan"]["predicted_rmse_mm"]
    )


def test_the_plan_delivers_its_promise_on_the_simulated_world(planned):
    # Measure the plan in three true cells (the tool moved onto each true line from the planned
    # pose, one reading per capture as the plan was asked to assume), calibrate, compare with the
    # truth: below the 95 % bound each time, and the RMS over the cells within 2x of the expected
    # value.
    plan, report, _ = planned
    robot, promise = load_robot(ROBOT), report["predicted"]["plan"]
    true = []
    for seed in (1, 2, 3):
        world = World.create(seed, n_lines=3)
        rng = np.random.default_rng(seed + 1000)
        q_true, ids = world.touch_lines(plan.q_deg, plan.line, rng)
        assert len(ids) >= 0.95 * len(plan)
        s = world.measure(q_true, ids, rng)
        samples = Samples("plan", "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line)
        out = calibration.calibrate_samples(samples, robot, SetupFile.model_validate(setup_dict(world, rng)))
        q = world.random_configurations(1000, np.random.default_rng(99))
        p = tcp_position(dh_table(out.calibration.x), np.radians(q), np.zeros(3))
        true.append(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))
    assert max(true) < promise["predicted_rmse_95_mm"]
    pooled = np.sqrt(np.mean(np.square(true)))
    assert promise["predicted_rmse_mm"] / 2 < pooled < 2 * promise["predicted_rmse_mm"]


def test_the_promise_counts_the_readings_a_capture_averages(tmp_path):
    # Each capture averages the config's [session] readings (K = 5 shipped): every row's noise is
    # the stated noise over sqrt(K), so the promise falls by nearly sqrt(K) (the priors do not).
    promises = {}
    for readings in ("1", None):
        report = tmp_path / f"{readings}.json"
        argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--out", str(tmp_path / "p.csv")]
        argv += ["--no-suggest", "--per-line", "30", "--report", str(report)]
        assert cli.main(argv + (["--readings", readings] if readings else [])) == 0
        data = json.loads(report.read_text())
        promises[data["readings"]] = data["predicted"]["plan"]["predicted_rmse_mm"]
    assert set(promises) == {1, 5}
    assert promises[1] / np.sqrt(5) < promises[5] < 1.1 * promises[1] / np.sqrt(5)


def _setup_without(tmp_path, key):
    data = read_toml(SETUP)
    for ln in data["lines"]:
        ln.pop(key, None)
    path = tmp_path / "setup.toml"
    path.write_text(tomli_w.dumps(data))
    return path


def test_a_setup_without_line_placements_is_a_one_line_error(tmp_path, capsys):
    setup = _setup_without(tmp_path, "point_mm")
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(setup), "--out", str(tmp_path / "p.csv")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "id 0: missing point_mm" in err
    assert not (tmp_path / "p.csv").exists()


def test_a_line_out_of_reach_is_a_one_line_error(tmp_path, capsys):
    data = read_toml(SETUP)
    data["lines"][1]["point_mm"] = [-4000.0, 0.0, 150.0]
    setup = tmp_path / "setup.toml"
    setup.write_text(tomli_w.dumps(data))
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(setup), "--out", str(tmp_path / "p.csv")]
    assert cli.main(argv) == 2
    errors = [ln for ln in capsys.readouterr().err.splitlines() if not ln.startswith("... ")]  # progress
    assert len(errors) == 1 and "id 1: only 0 of 100 points reachable" in errors[0]


def test_plan_reads_robot_and_setup_from_a_session_folder(tmp_path, capsys):
    session = tmp_path / "session"
    session.mkdir()
    content = {"robot": read_toml(ROBOT), "setup": read_toml(SETUP)}
    (session / "session.toml").write_text(tomli_w.dumps(content))
    argv = ["plan", str(session), "--out", str(tmp_path / "p.csv"), "--no-suggest", "--per-line", "30"]
    assert cli.main(argv) == 0
    plan = load_plan(tmp_path / "p.csv")
    assert set(plan.line) == {0, 1, 2}
    assert cli.main(["plan", "--out", str(tmp_path / "q.csv")]) == 2
    assert "needs --robot and --setup" in capsys.readouterr().err


def test_a_selection_below_the_unknowns_is_a_one_line_error(tmp_path, capsys):
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--out", str(tmp_path / "p.csv")]
    assert cli.main(argv + ["--select", "5", "--no-suggest"]) == 2
    errors = [ln for ln in capsys.readouterr().err.splitlines() if not ln.startswith("... ")]
    assert len(errors) == 1 and "--select 5:" in errors[0] and "unknowns" in errors[0]
