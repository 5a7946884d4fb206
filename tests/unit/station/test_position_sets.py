"""Position (tracker) sets with few rows through ``station calibrate``, as a user meets them: a
position report, or one line and exit 2; never a traceback (a 30-row set once ended in
``KeyError: 'lines'``, the drawstring warning asked of a position report)."""

import json
from pathlib import Path

import numpy as np
import pytest

from calib.kinematics import tcp_position
from calib.params import dh_from_degrees
from calib.position import rotation_from_vector
from station.cli import main
from station.formats.samples import load_samples
from station.formats.tables import load_robot
from station.jobs import calibration, fit_check
from station.jobs.report import WorkspacePrediction

ROBOT = Path(__file__).resolve().parents[3] / "configs/robots/ur10.toml"
SIGMA_MM = 0.02  # tracker noise per axis


def write_position_set(
    path: Path, n: int, seed: int = 5, sigma_mm: float = SIGMA_MM, sag_mm: float = 0.0
) -> None:
    """``n`` random poses within the joint limits of a UR10 with machining errors (0.15 deg,
    0.75 mm), its probe 100 mm out on the flange axis, seen by a tracker at an arbitrary pose with
    noise ``sigma_mm`` per axis; ``sag_mm``: the tool also sinks by that much times the square of its
    reach over a metre (an elastic sag, which no D-H table expresses)."""
    rng = np.random.default_rng(seed)
    robot = load_robot(ROBOT)
    true = dh_from_degrees(robot.table_deg()) + np.column_stack(
        [np.radians(rng.normal(0, 0.15, 6)), rng.normal(0, 0.75, (6, 2)), np.radians(rng.normal(0, 0.15, 6))]
    )
    limits = np.radians(robot.limits_deg())
    q = rng.uniform(limits[:, 0], limits[:, 1], (n, 6))
    tracker = rotation_from_vector(np.array([0.1, -0.2, 2.5]))
    p = tcp_position(true, q, np.array([0.0, 0.0, 100.0]))
    p[:, 2] -= sag_mm * np.sum(p[:, :2] ** 2, axis=1) / 1000.0**2
    p = p @ tracker.T + [2500.0, -1000.0, 200.0] + rng.normal(0, sigma_mm, p.shape)
    rows = ["sample,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm"]
    rows += [",".join(map(str, [k, *np.degrees(q[k]), *p[k]])) for k in range(n)]
    path.write_text("\n".join(rows) + "\n")


def calibrate(tmp_path, samples: Path) -> tuple[int, str, Path, Path]:
    out, report = tmp_path / "t.toml", tmp_path / "r.json"
    argv = ["calibrate", str(samples), "--robot", str(ROBOT), "--out", str(out), "--report", str(report)]
    return main(argv), out, report


def test_a_set_with_fewer_rows_than_unknowns_is_one_line(tmp_path, capsys):
    samples = tmp_path / "p10.csv"
    write_position_set(samples, 10)
    code, out, report = calibrate(tmp_path, samples)
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert f"{samples}: 10 samples cannot determine" in err
    assert not out.exists() and not report.exists()


def test_a_set_just_above_the_unknowns_calibrates_to_a_position_report(tmp_path, capsys):
    samples = tmp_path / "p30.csv"
    write_position_set(samples, 30)
    code, out, report = calibrate(tmp_path, samples)
    assert code == 0 and out.exists()
    r = json.loads(report.read_text())
    assert r["kind"] == "position" and {"tracker_from_base", "probe_mm"} <= set(r)
    assert not {"anchor_mm", "length_offset_mm", "lines"} & set(r)
    # fitted to the tracker's noise: |e| of 3-D Gaussian noise has RMS sqrt(3) sigma, less the
    # share the ~30 fitted unknowns absorb (90 residuals: about 0.8 of it)
    assert r["after"]["train"]["rmse_mm"] < np.sqrt(3) * SIGMA_MM
    # the prediction is of the measured point, whose last link's errors the fitted probe takes up:
    # no floor from J6 held at its tolerance (that put it at 0.49 mm whatever the poses)
    assert r["workspace"]["predicted_rmse_mm"] < 0.1
    # the one warning: 30 rows are too few to cross-validate terms (--model auto, the default)
    (warning,) = r["warnings"]
    assert "too few per fold" in warning and r["model"] == "auto" and r["terms"] == {}
    assert "predicted workspace error" in capsys.readouterr().out


def test_a_position_set_that_cannot_promise_the_workspace_says_what_to_measure(tmp_path):
    """Where the prediction is far above the fit, the warning names the poses and asks for more
    (this path once ended in ``KeyError: 'lines'``: the drawstring's warning asked of a position
    report)."""
    samples = tmp_path / "p30.csv"
    write_position_set(samples, 30)
    out = calibration.calibrate_samples(load_samples(samples), load_robot(ROBOT), None)
    fit = out.report.after.train
    far = WorkspacePrediction(20 * fit.rmse_mm + 1.0, 40 * fit.rmse_mm + 2.0, 1000)
    (warning,) = fit_check.workspace_warnings(out.model, out.calibration.x, fit, far)
    assert "fits its 30 poses to" in warning and "more configurations" in warning


@pytest.mark.parametrize("n, code", [(22, 2), (23, 0)])
def test_the_edge_of_enough_rows(tmp_path, capsys, n, code):
    """23 unknowns: the 24 table parameters and 9 of the tracker setup, less 10 gauges."""
    samples = tmp_path / f"p{n}.csv"
    write_position_set(samples, n, seed=n)
    assert calibrate(tmp_path, samples)[0] == code
    err = capsys.readouterr().err
    assert err == "" if code == 0 else f"{n} samples cannot determine 23 unknowns" in err


@pytest.mark.parametrize(("sigma_mm", "sag_mm", "robot_errs"), [(0.2, 0.0, False), (0.02, 3.0, True)])
def test_a_residual_beyond_the_noise_is_named_the_robot_s_or_the_instruments(
    tmp_path, capsys, sigma_mm, sag_mm, robot_errs
):
    """Tenfold the stated tracker noise: neighbouring poses do not err alike, check the instruments.
    A sag no table expresses (3 mm per square metre of reach): they do, accept with care."""
    samples = tmp_path / "p1000.csv"
    write_position_set(samples, 1000, sigma_mm=sigma_mm, sag_mm=sag_mm)
    code, _, report = calibrate(tmp_path, samples)
    out = capsys.readouterr().out
    check, advice = json.loads(report.read_text())["fit_check"], json.loads(report.read_text())["next"]
    assert code == 0 and check["noise_ratio"] > 4 and check["model_error"] is robot_errs
    if robot_errs:
        assert check["neighbour_agreement"] > 0.25
        assert advice.startswith("accept with care: the robot errs beyond this model")
        assert "the robot has an error this model does not express, not the instruments" in out
    else:
        assert abs(check["neighbour_agreement"]) < 4 / np.sqrt(3 * 1000)
        assert advice.startswith("re-measure after checking the instruments")
