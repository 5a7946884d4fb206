"""The report as the one record of a calibration: it names the robot, the samples, the setup, the
date and the version; puts each parameter beside its nominal value and each gauge line beside its
residual; and says in ``next`` what to do now, from what the fit found (simulated cells)."""

import json

import numpy as np
import tomli_w

from station import installed_version
from station.cli import main
from station.formats.base import read_toml


def _calibrate(capsys, robot, setup, samples, folder, *extra):
    report = folder / "report.json"
    argv = ["calibrate", samples, "--robot", robot, "--setup", setup, "--out", folder / "c.toml"]
    code = main([str(a) for a in (*argv, "--report", report, *extra)])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(report.read_text()), out


def test_the_report_stands_alone(three_lines, tmp_path, capsys):
    sc = three_lines
    robot = read_toml(sc.robot)
    with_serial = tmp_path / "robot.toml"
    with_serial.write_text(tomli_w.dumps({**robot, "serial": "JR680-0042"}))
    report, out = _calibrate(capsys, with_serial, sc.setup, sc.samples, tmp_path, "--holdout", sc.holdout)
    assert report["robot"] == {"name": "HSR-JR680", "serial": "JR680-0042", "convention": "dh"}
    assert report["samples"] == str(sc.samples) and report["setup"] == str(sc.setup)
    assert report["station_version"] == installed_version()
    assert report["created_utc"].endswith("+00:00")
    nominal = {f"J{j + 1}.{k}": v for j, joint in enumerate(robot["joints"]) for k, v in joint.items()}
    for name, p in report["parameters"].items():
        assert p["nominal"] == nominal[name]
        assert np.isclose(p["nominal"] + p["delta"], p["value"])
    # the lines' residuals make up the training rows' residual
    counts = np.bincount(sc.train.line)
    lines = report["lines"]
    assert [ln["id"] for ln in lines] == [0, 1, 2]
    pooled = np.sqrt(sum(counts[ln["id"]] * ln["rmse_mm"] ** 2 for ln in lines) / counts.sum())
    assert np.isclose(pooled, report["after"]["train"]["rmse_mm"])
    assert max(ln["max_mm"] for ln in lines) == report["after"]["train"]["max_mm"]
    check = report["fit_check"]
    assert check["excursion_tolerances"] == check["excursion_sigmas"] > 0
    assert report["holdout_scope"] == "same lines"
    assert "says nothing about the rest of the workspace" in out
    assert report["next"].startswith("accept: predicted workspace error")
    assert out.splitlines()[-2] == f"next: {report['next']}"


def test_without_a_holdout_the_station_says_what_its_figures_cover(three_lines, tmp_path, capsys):
    sc = three_lines
    report, out = _calibrate(capsys, sc.robot, sc.setup, sc.samples, tmp_path)
    assert report["holdout_scope"] == "none"
    assert "note: no --holdout: every figure but the predicted workspace error" in out


def test_one_line_asks_for_another_placement(one_line, tmp_path, capsys):
    sc = one_line
    report, _ = _calibrate(capsys, sc.robot, sc.setup, sc.samples, tmp_path)
    assert report["workspace"]["predicted_rmse_mm"] > 0.5
    assert report["next"].startswith("add a placement: add a line placement along [")


def test_instruments_worse_than_stated_ask_to_re_measure(three_lines, tmp_path, capsys):
    sc = three_lines
    setup = read_toml(sc.setup)
    setup["drawstring"]["sigma_mm"] /= 10  # the instruments read 10x worse than this file states
    quiet = tmp_path / "setup.toml"
    quiet.write_text(tomli_w.dumps(setup))
    report, _ = _calibrate(capsys, sc.robot, quiet, sc.samples, tmp_path)
    assert report["fit_check"]["verdict"] == "doubtful"
    assert report["next"].startswith("re-measure after checking the instruments and the setup's sigma_mm")
