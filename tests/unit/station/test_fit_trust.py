"""`station calibrate` as a user meets its judgement of the data: samples that cannot be this
robot's refused (exit 2, one line naming the likely cause, nothing written), a flag replacing a
session's robot said, good data passed without a word; a wild reading or rows of another session named;
``--plot``; an unwritable output found before the work."""

import json
import shutil

import matplotlib.image
import numpy as np
import pytest
import tomli_w

import configs
from calib.metrics import aligned_errors
from sim_fixtures.scenario import write_scenario
from station.cli import main
from station.formats.base import read_toml
from station.formats.tables import load_robot

UR10 = configs.path("robots/ur10.toml")


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def session(three_lines, tmp_path_factory):
    """A simulated JR680 session folder: the three-line cell's samples, its robot and setup embedded."""
    folder = tmp_path_factory.mktemp("session") / "run1"
    folder.mkdir()
    header = {"robot": read_toml(three_lines.robot), "setup": read_toml(three_lines.setup)}
    (folder / "session.toml").write_text(tomli_w.dumps(header))
    shutil.copy(three_lines.samples, folder / "samples.csv")
    return folder


def _with_row(samples, row, column, value, out):
    header, *rows = samples.read_text().splitlines()
    cells = rows[row].split(",")
    cells[header.split(",").index(column)] = value
    out.write_text("\n".join([header, *rows[:row], ",".join(cells), *rows[row + 1 :]]) + "\n")
    return out


def _outputs(folder):
    return folder / "o.toml", folder / "r.json", folder / "p.png"


@pytest.mark.parametrize(
    "with_session, cause",
    [
        (True, "likely cause: --robot {ur10} replaces the robot embedded in {session}/session.toml: name"),
        (False, "likely cause: a wrong robot model (the robot file describes the UR10)"),
    ],
)
def test_a_jr680_session_calibrated_with_the_ur10_table_is_refused(
    with_session, cause, session, three_lines, tmp_path, capsys
):
    samples = session if with_session else three_lines.samples
    setup = [] if with_session else ["--setup", three_lines.setup]
    out, report, plot = _outputs(tmp_path)
    argv = ["calibrate", samples, "--robot", UR10, *setup, "--out", out, "--report", report, "--plot", plot]
    # --model geometric: the table alone is refused the same way, and sooner
    code, stdout, err = _cli(capsys, *argv, "--model", "geometric")
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith(f"station: error: {samples}: these samples do not fit")
    assert "times the stated noise" in err and cause.format(ur10=UR10, session=session) in err
    assert err.endswith("; nothing written\n")
    assert list(tmp_path.iterdir()) == []


def test_a_good_session_passes_without_a_word_and_plots(session, tmp_path, capsys):
    out, report, plot = _outputs(tmp_path)
    code, stdout, _ = _cli(capsys, "calibrate", session, "--out", out, "--report", report, "--plot", plot)
    assert code == 0 and "warning" not in stdout
    assert f"wrote {out}, {report}, {plot}" in stdout
    data = json.loads(report.read_text())
    assert data["warnings"] == [] and data["fit_check"]["verdict"] == "consistent"
    # clean data at the stated noise: the residual within 2x of it (the joint noise adds a little)
    assert 0.5 < data["fit_check"]["noise_ratio"] < 2.0
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(plot)
    height, width = image.shape[:2]
    assert width >= 1200 and 400 <= height <= width / 2  # three panels side by side
    assert np.std(image[..., :3]) > 0.05  # drawn on, not a blank page


def test_a_robot_given_for_a_session_is_said_unless_it_is_the_same(session, tmp_path, capsys):
    corrected = tmp_path / "corrected.toml"
    assert _cli(capsys, "calibrate", session, "--out", corrected, "--model", "geometric")[0] == 0
    embedded = tmp_path / "jr680.toml"
    embedded.write_text(tomli_w.dumps(read_toml(session / "session.toml")["robot"]))
    report = tmp_path / "r.json"
    for robot, note in ((embedded, False), (corrected, True)):
        argv = ["calibrate", session, "--robot", robot, "--out", tmp_path / "o.toml", "--report", report]
        code, stdout, _ = _cli(capsys, *argv, "--model", "geometric")
        said = f"--robot {robot} replaces the robot embedded in {session / 'session.toml'}: joints."
        assert code == 0 and (f"warning: {said}" in stdout) == note
        assert any(w.startswith(said) for w in json.loads(report.read_text())["warnings"]) == note


def test_an_output_that_cannot_be_written_is_found_before_the_work(three_lines, tmp_path, capsys):
    # A folder that is a file: refused before the solve, nothing of the others written.
    (tmp_path / "file").write_text("")
    out, report, _ = _outputs(tmp_path)
    plot = tmp_path / "file" / "p.png"
    argv = ["calibrate", three_lines.samples, "--robot", three_lines.robot, "--setup", three_lines.setup]
    code, _, err = _cli(capsys, *argv, "--out", out, "--report", report, "--plot", plot)
    assert code == 2 and err.count("\n") == 1 and f"--plot {plot}: folder" in err
    assert not out.exists() and not report.exists()


def test_a_wild_reading_is_left_out_named_and_asked_for_again(three_lines, tmp_path, capsys):
    """A 100 m cable reading among 1 m ones: the fit leaves it out (robust from its first round, at
    the setup fit's noise), names the row and asks for it again; the table is the clean rows' own."""
    wild = _with_row(three_lines.samples, 5, "length_mm", "99999.0", tmp_path / "wild.csv")
    robot_flags = ["--robot", three_lines.robot, "--setup", three_lines.setup, "--model", "geometric"]
    tables = {}
    for name, rows in (("wild", wild), ("clean", three_lines.samples)):
        out_flags = ["--out", tmp_path / f"{name}.toml", "--report", tmp_path / f"{name}.json"]
        code, out, _ = _cli(capsys, "calibrate", rows, *robot_flags, *out_flags)
        assert code == 0
        tables[name] = load_robot(tmp_path / f"{name}.toml").model()
    report = json.loads((tmp_path / "wild.json").read_text())
    assert 5 in report["downweighted"]
    assert any(
        w.startswith("row 5: error before calibration up to") and "a wild reading" in w
        for w in report["warnings"]
    )
    assert report["next"].startswith("re-measure row 5 (error before calibration up to")
    # the two tables agree over the workspace far inside what the clean calibration promises: one
    # row of 150 moves the fit by a fraction of its uncertainty (about sqrt(1 / 25) for 25 unknowns)
    q = np.radians(np.random.default_rng(0).uniform(-60, 60, (500, 6)))
    p = {name: model.tool_frames(q)[0] for name, model in tables.items()}
    bound = json.loads((tmp_path / "clean.json").read_text())["workspace"]["predicted_rmse_mm"]
    assert np.sqrt(np.mean(aligned_errors(p["wild"], p["clean"]) ** 2)) < 0.2 * bound


def test_wild_readings_the_fit_cannot_leave_out_are_named_as_the_likely_cause(three_lines, tmp_path, capsys):
    """Every third reading 1 m off: too many to leave out; refused, naming rows."""
    header, *rows = three_lines.samples.read_text().splitlines()
    k = header.split(",").index("length_mm")
    for i in range(0, len(rows), 3):
        cells = rows[i].split(",")
        cells[k] = str(float(cells[k]) + 1000.0)
        rows[i] = ",".join(cells)
    wild = tmp_path / "wild.csv"
    wild.write_text("\n".join([header, *rows]) + "\n")
    argv = ["calibrate", wild, "--robot", three_lines.robot, "--setup", three_lines.setup]
    code, _, err = _cli(capsys, *argv, "--model", "geometric", "--out", tmp_path / "o.toml")
    assert code == 2 and err.count("\n") == 1
    assert "likely cause: rows 0, 3, 6, " in err and "a wild reading" in err
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.parametrize("reading", ["3590.0", "-171.5"])
def test_a_joint_beyond_the_robot_files_limits_is_refused_naming_it(three_lines, tmp_path, capsys, reading):
    # within the loader's ten turns, but no angle the JR680's joint 1 (-170 .. 170 deg) can take
    bad = _with_row(three_lines.samples, 7, "q1_deg", reading, tmp_path / "bad.csv")
    argv = ["calibrate", bad, "--robot", three_lines.robot, "--setup", three_lines.setup]
    code, _, err = _cli(capsys, *argv, "--out", tmp_path / "o.toml")
    assert code == 2 and err.count("\n") == 1
    where = f"bad.csv: row 7 (line 9): q1_deg {float(reading):g}"
    assert f"{where} is outside joint 1's limits -170 .. 170 deg" in err
    assert not (tmp_path / "o.toml").exists()


@pytest.mark.parametrize("past_deg, code", [(0.5, 0), (1.5, 2)])
def test_a_joint_within_a_degree_past_its_limit_is_overtravel(three_lines, tmp_path, capsys, past_deg, code):
    """The clean samples against a robot file whose joint 1 ends ``past_deg`` below the highest q1."""
    robot = read_toml(three_lines.robot)
    header, *rows = three_lines.samples.read_text().splitlines()
    q1 = max(float(r.split(",")[header.split(",").index("q1_deg")]) for r in rows)
    robot["joints"][0]["q_max_deg"] = q1 - past_deg
    (tmp_path / "robot.toml").write_text(tomli_w.dumps(robot))
    robot_flags = ["--robot", tmp_path / "robot.toml", "--setup", three_lines.setup]
    argv = ["calibrate", three_lines.samples, *robot_flags]
    assert _cli(capsys, *argv, "--model", "geometric", "--out", tmp_path / "o.toml")[0] == code


def test_rows_of_another_session_mixed_in_are_named_as_the_likely_cause(three_lines, tmp_path, capsys):
    # 40 rows of another cell (its own robot and anchor) appended to this one's 150
    other = write_scenario(tmp_path / "other", seed=5, n_lines=1, n_per_line=40)
    header, *rows = three_lines.samples.read_text().splitlines()
    mixed = tmp_path / "mixed.csv"
    mixed.write_text("\n".join([header, *rows, *other.samples.read_text().splitlines()[1:]]) + "\n")
    argv = ["calibrate", mixed, "--robot", three_lines.robot, "--setup", three_lines.setup]
    code, _, err = _cli(capsys, *argv, "--model", "geometric", "--out", tmp_path / "o.toml")
    assert code == 2 and err.count("\n") == 1 and "rows lie hundreds of noise sigmas off the rest" in err
    assert "likely cause: samples of different sessions (or of a cell that changed) in one set" in err
    assert not (tmp_path / "o.toml").exists()
