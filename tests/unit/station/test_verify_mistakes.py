"""``station verify`` refuses, as ``station calibrate`` does, what cannot judge a table or is the
user's mistake rather than the robot's drift: one pose read many times, another robot's table, a
flipped dial axis, a table whose calibration block is not a calibration's, a table of another
serial. Each is one line, exit 2, and no record in the robot's history."""

import json

import numpy as np
import pytest
import tomli_w

import configs
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import World
from station.cli import main
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs.planning import verify_design

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROBOT = configs.path("robots/hsr_jr680.toml")


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """A simulated JR680 cell calibrated from 3 lines x 40 poses, and a 30-pose verification set."""
    folder = tmp_path_factory.mktemp("verify-mistakes")
    world = World.create(2)
    rng = np.random.default_rng([2, 1])
    (folder / "setup.toml").write_text(tomli_w.dumps(setup_dict(world, rng)))
    world.sample_set(40, rng, readings=5).to_csv(folder / "train.csv")
    plan = verify_design(load_robot(ROBOT), load_setup(configs.path("setups/sim.toml")), n_select=30).plan
    q, lines = world.touch_lines(plan.q_deg, plan.line, rng)
    world.measure(q, lines, rng, readings=5).to_csv(folder / "verify.csv")
    db = folder / "cell.sqlite"
    args = ["--robot", str(ROBOT), "--setup", str(folder / "setup.toml"), "--db", str(db)]
    assert main(["calibrate", str(folder / "train.csv"), "--out", str(folder / "table.toml"), *args]) == 0
    return folder, db


def _verify(capsys, folder, db, *argv) -> tuple[int, str]:
    capsys.readouterr()
    (folder / "v.json").unlink(missing_ok=True)
    code = main(["verify", *argv, "--db", str(db), "--report", str(folder / "v.json")])
    return code, capsys.readouterr().err


def _commands(capsys, db) -> list[str]:
    """The commands the history holds records of, for every robot."""
    assert main(["history", "--db", str(db), "--json"]) == 0
    robots = json.loads(capsys.readouterr().out)
    found = []
    for robot in robots:
        assert main(["history", robot["robot"], "--db", str(db), "--json"]) == 0
        found += [r["command"] for r in json.loads(capsys.readouterr().out)["records"]]
    return found


def _refused(capsys, folder, db, code, err, *said):
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for text in said:
        assert text in err, err
    assert not (folder / "v.json").exists()
    assert _commands(capsys, db) == ["calibrate"]


def test_the_good_table_holds_on_the_verification_set(cell, capsys):
    """What the refusals below are measured against: the same files, a verdict."""
    folder, db = cell
    code, _ = _verify(
        capsys, folder, db, str(folder / "verify.csv"), "--table", str(folder / "table.toml"),
        "--robot", str(ROBOT), "--setup", str(folder / "setup.toml"), "--no-history",
    )  # fmt: skip
    assert code == 0


def test_one_pose_read_fifteen_times_cannot_judge_a_table(cell, capsys):
    """It verified as 'holds' at 0.00x the noise, the nominal table too."""
    folder, db = cell
    rows = (folder / "verify.csv").read_text().splitlines()
    (folder / "one-pose.csv").write_text("\n".join([rows[0], *[rows[1]] * 15]) + "\n")
    for table in (folder / "table.toml", ROBOT):
        code, err = _verify(
            capsys, folder, db, str(folder / "one-pose.csv"), "--table", str(table),
            "--robot", str(ROBOT), "--setup", str(folder / "setup.toml"),
        )  # fmt: skip
        _refused(capsys, folder, db, code, err, "15 samples at 1 distinct pose cannot judge a table")


def test_another_robots_table_is_the_users_mistake_not_a_drift(cell, capsys):
    """The UR10's table on the JR680's samples was 'drifted' (J2.theta_deg moved -71 deg) and put a
    drifted record in the UR10's history."""
    folder, db = cell
    ur10 = configs.path("robots/ur10.toml")
    setup = str(folder / "setup.toml")
    samples = str(folder / "verify.csv")
    code, err = _verify(capsys, folder, db, samples, "--table", str(ur10), "--setup", setup)
    _refused(capsys, folder, db, code, err, "these samples do not fit this table", "it describes the UR10")


def test_a_flipped_dial_axis_is_named_with_its_fix(cell, capsys):
    """It was 'drifted', exit 3, naming J3.theta_deg."""
    folder, db = cell
    line = int(load_samples(folder / "verify.csv").line[0])  # the verification set's one line
    setup = tomllib.loads((folder / "setup.toml").read_text())
    entry = next(e for e in setup["lines"] if e["id"] == line)
    entry["dial_axis"] = [-v for v in entry["dial_axis"]]
    (folder / "flipped.toml").write_text(tomli_w.dumps(setup))
    code, err = _verify(
        capsys, folder, db, str(folder / "verify.csv"), "--table", str(folder / "table.toml"),
        "--robot", str(ROBOT), "--setup", str(folder / "flipped.toml"),
    )  # fmt: skip
    said = f"line {line}'s dial readings run against its dial_axis"
    _refused(capsys, folder, db, code, err, said, "flip it")


@pytest.mark.parametrize("value", ["1e300", "inf", '"x"', "-1.0"])
def test_a_noise_scale_that_no_calibration_writes_is_refused_at_load(cell, capsys, value):
    """1e300 or inf made 'holds' of a table 17x off; a string was a ValueError traceback."""
    folder, db = cell
    text = (folder / "table.toml").read_text()
    table = tomllib.loads(text)
    scale = ", ".join([value] + [repr(v) for v in table["calibration"]["noise_scale"][1:]])
    start = text.index("noise_scale = [")
    end = text.index("]", start) + 1
    (folder / "odd.toml").write_text(text[:start] + f"noise_scale = [{scale}]" + text[end:])
    code, err = _verify(
        capsys, folder, db, str(folder / "verify.csv"), "--table", str(folder / "odd.toml"),
        "--robot", str(ROBOT), "--setup", str(folder / "setup.toml"),
    )  # fmt: skip
    _refused(capsys, folder, db, code, err, "odd.toml", "calibration.noise_scale")


def test_a_table_of_another_serial_is_refused(cell, capsys):
    """Robot B's file with robot A's table was accepted silently, and B's history got A's table."""
    folder, db = cell
    table = tomllib.loads((folder / "table.toml").read_text())
    (folder / "table-a.toml").write_text(tomli_w.dumps({**table, "serial": "A-1001"}))
    robot = tomllib.loads(ROBOT.read_text())
    (folder / "robot-b.toml").write_text(tomli_w.dumps({**robot, "serial": "B-2002"}))
    code, err = _verify(
        capsys, folder, db, str(folder / "verify.csv"), "--table", str(folder / "table-a.toml"),
        "--robot", str(folder / "robot-b.toml"), "--setup", str(folder / "setup.toml"),
    )  # fmt: skip
    _refused(capsys, folder, db, code, err, "serial 'A-1001'", "'B-2002'")
