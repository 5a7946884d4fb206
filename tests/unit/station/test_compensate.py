"""`station compensate` as a user runs it, judged against the simulated truth: a three-line cell is
calibrated, a 1,000-pose program written with the nominal model is compensated, and the true robot
runs it. Bad input exits 2 with one line and writes nothing."""

import csv
import json
import re

import numpy as np
import pytest
import tomli_w
import tomllib

from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from station.cli import main
from station.formats.base import toml_text
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs.calibration import calibrate_samples
from station.jobs.report import corrected_table


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _rms(e):
    return float(np.sqrt(np.mean(e**2)))


@pytest.fixture(scope="module")
def cell(three_lines, tmp_path_factory):
    """The three-line cell calibrated (corrected.toml), and a 1,000-pose program within the limits."""
    sc = three_lines
    folder = tmp_path_factory.mktemp("compensate")
    samples, robot = load_samples(sc.samples), load_robot(sc.robot)
    outcome = calibrate_samples(samples, robot, load_setup(sc.setup))
    corrected = folder / "corrected.toml"
    corrected.write_text(toml_text(corrected_table(robot, outcome.calibration, samples, "lmlc")))
    q = sc.world.random_configurations(1000, np.random.default_rng(11))
    program = folder / "program.csv"
    with program.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["step", *(f"q{i}_deg" for i in range(1, 7)), "speed"])
        for i, qi in enumerate(q):
            writer.writerow([i, *(f"{v:.6f}" for v in qi), "v100"])
    return sc, outcome, corrected, program, q


def _status_parts(status: str) -> tuple[str, list[float]]:
    """A row's status as its words (each figure a ``#``) and its figures."""
    return re.sub(r"\d+\.\d+", "#", status), [float(v) for v in re.findall(r"\d+\.\d+", status)]


def _compensated(path):
    rows = list(csv.DictReader(path.open()))
    q = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in rows])
    return rows, q


def test_compensated_program_is_as_accurate_as_the_table(cell, tmp_path, capsys):
    sc, outcome, corrected, program, q_program = cell
    out, report_path = tmp_path / "out.csv", tmp_path / "report.json"
    code, text, _ = _cli(
        capsys,
        "compensate",
        program,
        "--table",
        corrected,
        "--robot",
        sc.robot,
        "--out",
        out,
        "--report",
        report_path,
    )
    assert code == 0, text
    rows, q_out = _compensated(out)
    ok = np.array([r["status"] == "ok" for r in rows])
    assert ok.mean() > 0.7  # random poses: the rest are near singularities, and say so
    assert [r["step"] for r in rows] == [str(i) for i in range(1000)] and {r["speed"] for r in rows} == {
        "v100"
    }
    world = sc.world
    meant = world.nominal.tcp(q_program[ok])
    uncompensated = _rms(aligned_errors(meant, world.true_tcp_mm(q_program[ok])))
    compensated = _rms(aligned_errors(meant, world.true_tcp_mm(q_out[ok])))
    dh = dh_table(outcome.calibration.x)
    table = _rms(
        aligned_errors(
            tcp_position(dh, np.radians(q_program[ok]), np.zeros(3)), world.true_tcp_mm(q_program[ok])
        )
    )
    assert compensated <= 1.5 * table
    assert compensated * 20 <= uncompensated
    # rows that keep their joints keep them exactly, and say why
    kept = ~ok
    np.testing.assert_allclose(q_out[kept], q_program[kept], atol=1e-6)
    assert all(r["status"].startswith("kept: ") and float(r["shift_mm"]) == 0.0 for r in np.array(rows)[kept])
    report = json.loads(report_path.read_text())
    assert report["rows"] == 1000 and report["compensated"] == int(ok.sum())
    assert sum(report["status_counts"].values()) == 1000
    assert [f["row"] for f in report["flagged"]] == list(np.flatnonzero(kept))
    shifts = np.array([float(r["shift_mm"]) for r in rows])[ok]
    assert report["shift_mm"]["max"] == pytest.approx(shifts.max(), abs=1e-4)
    # the promise for the program: the calibration's own workspace prediction, over these poses
    predicted = report["predicted"]["rmse_mm"]
    assert predicted == pytest.approx(outcome.report.workspace.predicted_rmse_mm, rel=0.25)
    assert report["predicted"]["rmse_95_mm"] > predicted
    assert f"{predicted:.3f} mm RMS" in text and "joint targets" in text


def test_the_covariance_reads_back(cell):
    _, outcome, corrected, _, _ = cell
    cov = load_robot(corrected).covariance(str(corrected))
    np.testing.assert_allclose(cov, outcome.calibration.robot_covariance, rtol=1e-12, atol=1e-300)


def test_a_table_without_covariance_compensates_and_says_so(cell, tmp_path, capsys):
    sc, _, _, program, _ = cell
    out, report = tmp_path / "out.csv", tmp_path / "r.json"
    code, text, _ = _cli(
        capsys,
        "compensate",
        program,
        "--table",
        sc.robot,
        "--robot",
        sc.robot,
        "--out",
        out,
        "--report",
        report,
    )
    assert code == 0
    assert "no predicted accuracy" in text
    data = json.loads(report.read_text())
    assert data["predicted"] is None and data["shift_mm"]["max"] < 1e-6


def _write(path, header, rows):
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


@pytest.mark.parametrize(
    ("header", "rows", "message"),
    [
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg", ["0,-50,-20,0,-40"], "missing column q6_deg"),
        (
            "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg",
            ["0,-50,-20,0,-40,0", "0,-50,nan,0,-40,0"],
            "row 1 (line 3): q3_deg: 'nan'",
        ),
        (
            "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg",
            ["0,-50,-20,inf,-40,0"],
            "row 0 (line 2): q4_deg: 'inf'",
        ),
        (
            "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg",
            ["0,-50,-20,0,,0"],
            "row 0 (line 2): q5_deg: '(empty)'",
        ),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg", ["0,-50,-20,0,-40,0,7"], "row 0 (line 2): 7 cells"),
        ("q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg", [], "no program rows"),
        (
            "q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,shift_mm,status",
            ["0,-50,-20,0,-40,0,1.0,ok"],
            "compensated program already",
        ),
    ],
)
def test_bad_program(header, rows, message, cell, tmp_path, capsys):
    sc, _, corrected, _, _ = cell
    bad, out = _write(tmp_path / "bad.csv", header, rows), tmp_path / "out.csv"
    code, _, err = _cli(capsys, "compensate", bad, "--table", corrected, "--robot", sc.robot, "--out", out)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"station: error: {bad}: ") and message in lines[0], err
    assert not out.exists()


def test_bad_table_robot_or_output(cell, tmp_path, capsys):
    sc, _, corrected, program, _ = cell
    five = tmp_path / "five.toml"
    five.write_text(corrected.read_text().replace("[[joints]]", "[[joints]]", 5).rsplit("[[joints]]", 1)[0])
    ur10 = tmp_path / "ur10.toml"
    ur10.write_text(
        (sc.robot.parent / "robot.toml").read_text().replace("653.5", "127.3").replace("1030.2", "163.9")
    )
    broken = tmp_path / "broken.toml"
    broken.write_text(corrected.read_text().replace("covariance = [", "covariance = [ [ 1.0,], ", 1))
    asymmetric = tmp_path / "asymmetric.toml"  # one off-diagonal entry of -1e308 (issue 15's fuzz)
    data = tomllib.loads(corrected.read_text())
    data["calibration"]["covariance"][11][0] = -1e308
    asymmetric.write_text(tomli_w.dumps(data))
    out = tmp_path / "out.csv"
    cases = [
        (("--table", five, "--robot", sc.robot, "--out", out), f"{five}: joints: expected 6 joints, got 5"),
        (("--table", asymmetric, "--robot", sc.robot, "--out", out), "covariance: not a covariance"),
        (("--table", corrected, "--robot", ur10, "--out", out), "not a calibration of that robot"),
        (("--table", broken, "--robot", sc.robot, "--out", out), "calibration.covariance"),
        (("--table", corrected, "--robot", sc.robot, "--out", tmp_path / "none" / "o.csv"), "does not exist"),
        (("--table", corrected, "--robot", sc.robot, "--out", out, "--report", tmp_path), "is a directory"),
    ]
    for argv, message in cases:
        code, _, err = _cli(capsys, "compensate", program, *argv)
        assert code == 2, argv
        assert len(err.strip().splitlines()) == 1 and message in err, err
        assert not out.exists()


def test_status_says_why_a_row_keeps_its_joints(cell, tmp_path, capsys):
    sc, _, corrected, _, _ = cell
    program = _write(
        tmp_path / "p.csv",
        "name,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg",
        ["work,0,-50,-20,0,-40,0", "high,0,95,-20,0,-40,0", "wrist,0,-50,-20,30,-93,10"],
    )
    out = tmp_path / "out.csv"
    code, text, _ = _cli(
        capsys, "compensate", program, "--table", corrected, "--robot", sc.robot, "--out", out
    )
    assert code == 0
    status = {r["name"]: r["status"] for r in csv.DictReader(out.open())}
    assert status == {
        "work": "ok",
        "high": "kept: q2 outside its limits -150 to 90 deg",
        "wrist": "kept: axes 4 and 6 3.0 deg apart, within the wrist singularity margin 10 deg",
    }
    assert "1 outside limits, 1 wrist singularity" in text
    code, _, _ = _cli(
        capsys,
        "compensate",
        program,
        "--table",
        corrected,
        "--robot",
        sc.robot,
        "--out",
        out,
        "--wrist-margin-deg",
        "2",
    )
    assert code == 0
    assert [r["status"] for r in csv.DictReader(out.open())][2] != status["wrist"]


def test_a_program_in_a_controllers_convention_is_compensated_in_its_convention(cell, tmp_path, capsys):
    """A KUKA-like ``[controller]`` in the robot file: the program's joints are the controller's,
    converted to the model's to compensate and back to write; the result is the model program's
    compensation in the controller's joints, and a kept row keeps the program's joints."""
    sc, _, corrected, program, q_program = cell
    sign, offset = np.array([-1, 1, 1, -1, 1, -1]), np.array([0.0, -90.0, 90.0, 0.0, 0.0, 0.0])
    robot = tmp_path / "kuka.toml"
    controller = {"joint_sign": sign.tolist(), "joint_offset_deg": offset.tolist()}
    robot.write_text(sc.robot.read_text() + "\n" + tomli_w.dumps({"controller": controller}))
    kuka_table = (
        tmp_path / "kuka_corrected.toml"
    )  # calibrated from this robot file, it carries its convention
    kuka_table.write_text(corrected.read_text() + "\n" + tomli_w.dumps({"controller": controller}))
    in_controller = tmp_path / "program_kuka.csv"
    rows = list(csv.DictReader(program.open()))
    with in_controller.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for row, q in zip(rows, q_program, strict=True):
            reading = sign * (q - offset)  # the contract: q_model = sign * reading + offset
            writer.writerow({**row, **{f"q{i + 1}_deg": f"{v:.6f}" for i, v in enumerate(reading)}})
    model_out, kuka_out = tmp_path / "model.csv", tmp_path / "kuka.csv"
    args = ("--table", corrected, "--out")
    assert _cli(capsys, "compensate", program, "--robot", sc.robot, *args, model_out)[0] == 0
    assert (
        _cli(capsys, "compensate", in_controller, "--robot", robot, "--table", kuka_table, "--out", kuka_out)[
            0
        ]
        == 0
    )
    model_rows, q_model = _compensated(model_out)
    kuka_rows, q_kuka = _compensated(kuka_out)
    # the same statuses; their figures (mm, deg left) to one unit of the last digit printed: the two
    # conversions differ by 1e-9 mm, enough to round a figure the other way
    words = [[_status_parts(r["status"])[0] for r in rows] for rows in (kuka_rows, model_rows)]
    assert words[0] == words[1]
    for kuka_row, model_row in zip(kuka_rows, model_rows, strict=True):
        figures = _status_parts(kuka_row["status"])[1], _status_parts(model_row["status"])[1]
        np.testing.assert_allclose(figures[0], figures[1], rtol=0, atol=1.01e-4)
    # each file's joints to 6 decimals: the two agree to twice that rounding
    np.testing.assert_allclose(sign * q_kuka + offset, q_model, atol=2e-6)
    kept = [k for k, r in enumerate(kuka_rows) if r["status"] != "ok"]
    given = list(csv.DictReader(in_controller.open()))
    q_cols = [f"q{i}_deg" for i in range(1, 7)]
    assert kept and all([kuka_rows[k][c] for c in q_cols] == [given[k][c] for c in q_cols] for k in kept)
