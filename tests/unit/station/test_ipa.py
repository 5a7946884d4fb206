"""The IPA dataset reader and ``station import-ipa``: the real files (skipped when the dataset is
absent), bad files (exit 2, one line), and the round trip to the contract's position CSV."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from errors import InputError
from station.cli import main
from station.formats.ipa import probe_file_for, read_probe_mm, read_series
from station.formats.samples import load_samples

ROOT = Path(__file__).resolve().parents[3]
DATA = Path(os.environ.get("STATION_IPA_DATA", ROOT / "../shared/datasets/ipa-robot-accuracy"))
SERIES_D = DATA / "Series_D/measurements_iso_cubes.csv"
SERIES_B = DATA / "Series_B/measurements_joint_configurations.csv"
needs_data = pytest.mark.skipif(
    not SERIES_D.exists(), reason=f"IPA dataset not found at {DATA} (set STATION_IPA_DATA)"
)

HEADER = (
    "Timestamp;shoulder_pan_joint;shoulder_lift_joint;elbow_joint;wrist_1_joint;wrist_2_joint;"
    "wrist_3_joint;measurement_x;measurement_y;measurement_z"
)
ROW = "2,02103E+13;0,93;-1,79;1,52;0,27;0,93;-1,57;2336,7643;-905,76441;-454,63664"


@needs_data
def test_reads_series_d_as_published():
    """632 ISO-cube poses; first row's values as printed in the file (radians, mm)."""
    series = read_series(SERIES_D)
    assert len(series) == 632
    np.testing.assert_allclose(series.q_rad[0], [0.934319, -1.79251, 1.5196, 0.272862, 0.934269, -1.57075])
    np.testing.assert_allclose(series.position_mm[0], [2336.7643, -905.76441, -454.63664])
    np.testing.assert_allclose(read_probe_mm(probe_file_for(SERIES_D)), [0.0, 0.0, 109.0], atol=1e-3)
    assert series.temperature_c[0] == pytest.approx(20.7425, abs=1e-6)
    assert 20.7 < series.temperature_c.min() and series.temperature_c.max() < 20.9


def test_temperature_is_read_where_the_file_has_it(tmp_path):
    with_t, without = tmp_path / "t.csv", tmp_path / "n.csv"
    with_t.write_text(HEADER + ";measurement_temperature\n" + ROW + ";21,5\n")
    without.write_text(HEADER + "\n" + ROW + "\n")
    assert read_series(with_t).temperature_c.tolist() == [21.5]
    assert np.isnan(read_series(without).temperature_c).all()


@needs_data
def test_import_ipa_round_trip(tmp_path):
    out = tmp_path / "d.csv"
    assert main(["import-ipa", str(SERIES_D), "--out", str(out)]) == 0
    samples, series = load_samples(out), read_series(SERIES_D)
    assert samples.kind == "position"
    np.testing.assert_allclose(np.radians(samples.q_deg), series.q_rad, atol=1e-10)
    np.testing.assert_allclose(samples.measured, series.position_mm, atol=1e-6)


@pytest.mark.parametrize(
    "body, message",
    [
        ("", "empty file"),
        (HEADER.replace("elbow_joint", "elbow") + "\n" + ROW, "missing column 'elbow_joint'"),
        (HEADER + "\n", "no data rows"),
        (
            HEADER + "\n" + ROW.replace("2336,7643", "n/a"),
            "line 2, column 'measurement_x': 'n/a' is not a finite number",
        ),
        (
            HEADER + "\n" + ROW.replace("2336,7643", "1e308"),
            "line 2, column 'measurement_x': '1e308' is outside -100000 .. 100000 mm",
        ),
        (HEADER + "\n" + ROW + ";1", "line 2: 11 fields, the header has 10"),
    ],
)
def test_bad_series_exits_2_with_one_line(tmp_path, capsys, body, message):
    bad = tmp_path / "bad.csv"
    bad.write_text(body)
    out = tmp_path / "out.csv"
    assert main(["import-ipa", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err and str(bad) in err
    assert not out.exists()


def test_missing_series_and_bad_probe_file(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        read_series(tmp_path / "absent.csv")
    probe = tmp_path / "Trafo_TM_F_init.txt"
    probe.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    with pytest.raises(InputError, match="4x4"):
        read_probe_mm(probe)
    probe.write_text("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(InputError, match="not a rotation"):
        read_probe_mm(probe)


def test_small_series_round_trip_without_the_dataset(tmp_path):
    src = tmp_path / "s.csv"
    src.write_text(HEADER + "\n" + ROW + "\n" + ROW.replace("0,93;", "-0,5;", 1) + "\n")
    out = tmp_path / "s_out.csv"
    assert main(["import-ipa", str(src), "--out", str(out)]) == 0
    samples = load_samples(out)
    np.testing.assert_allclose(samples.q_deg[:, 0], np.degrees([0.93, -0.5]))
    np.testing.assert_allclose(samples.measured[1], [2336.7643, -905.76441, -454.63664])


@needs_data
def test_station_calibrate_on_a_real_position_set(tmp_path):
    """Every 3rd row of series D through the CLI: a position report, and the table fit cuts the
    registered error well below the nominal model's (measured: 0.77 -> 0.5 mm on all of D)."""
    full = tmp_path / "d.csv"
    assert main(["import-ipa", str(SERIES_D), "--out", str(full)]) == 0
    lines = full.read_text().splitlines()
    part = tmp_path / "d3.csv"
    part.write_text("\n".join(lines[:1] + lines[1::3]) + "\n")
    report = tmp_path / "r.json"
    robot = ROOT / "configs/robots/ur10.toml"
    args = [
        "calibrate",
        str(part),
        "--robot",
        str(robot),
        "--out",
        str(tmp_path / "c.toml"),
        "--report",
        str(report),
    ]
    assert main(args) == 0
    r = json.loads(report.read_text())
    assert r["kind"] == "position"
    assert r["after"]["train"]["rmse_mm"] < 0.8 * r["before"]["train"]["rmse_mm"]
    assert {"J1.theta_deg", "J6.d_mm"} <= {h["param"] for h in r["held"]}


@needs_data
def test_station_calibrate_on_the_first_30_rows_of_series_b(tmp_path):
    """Few rows of a real tracker set: a position report, whose 30 poses promise less over the
    workspace than they fit (this once ended in ``KeyError: 'lines'``)."""
    full = tmp_path / "b.csv"
    assert main(["import-ipa", str(SERIES_B), "--out", str(full)]) == 0
    part = tmp_path / "b30.csv"
    part.write_text("\n".join(full.read_text().splitlines()[:31]) + "\n")
    report = tmp_path / "r.json"
    robot = ROOT / "configs/robots/ur10.toml"
    argv = ["calibrate", str(part), "--robot", str(robot), "--out", str(tmp_path / "t.toml")]
    assert main(argv + ["--report", str(report)]) == 0
    r = json.loads(report.read_text())
    assert r["kind"] == "position" and "tracker_from_base" in r and "lines" not in r
    assert r["workspace"]["predicted_rmse_mm"] > 2 * r["after"]["train"]["rmse_mm"]


REGISTERED = {  # benchmarks/ipa_ur10.py --train X --test ..., position --model auto: RMSE / MEAN / MAX [mm]
    "B": (
        SERIES_B,
        {
            "C": ("Series_C/measurements_random_poses.csv", (0.506, 0.456, 1.463)),
            "D": ("Series_D/measurements_iso_cubes.csv", (0.393, 0.355, 1.213)),
        },
    ),
    # D's rows cover the whole turn of J1, J3, J4 and J5: their first harmonics are in its table
    "D": (SERIES_D, {"B": ("Series_B/measurements_joint_configurations.csv", (0.464, 0.418, 2.076))}),
}


@needs_data
@pytest.mark.parametrize("train", sorted(REGISTERED))
def test_verify_with_the_table_of_one_series_gives_the_benchmarks_figures(tmp_path, capsys, train):
    """``station verify`` is the benchmark's registration: the table of one series (``station
    calibrate``'s default model) held, each test series' tracker transform and probe fitted; to 1 %."""
    robot = str(ROOT / "configs/robots/ur10.toml")
    source, tests = REGISTERED[train]
    table = str(tmp_path / "T.toml")
    assert main(["import-ipa", str(source), "--out", str(tmp_path / "T.csv")]) == 0
    calibrate = ["calibrate", str(tmp_path / "T.csv"), "--robot", robot, "--out", table, "--no-map"]
    assert main(calibrate) == 0  # the table alone: the benchmark's figures
    for name, (series, registered) in tests.items():
        assert main(["import-ipa", str(DATA / series), "--out", str(tmp_path / f"{name}.csv")]) == 0
        report = tmp_path / f"V{name}.json"
        code = main(["verify", str(tmp_path / f"{name}.csv"), "--table", table, "--report", str(report)])
        found = json.loads(report.read_text())
        assert code == 0 and found["verdict"] == "holds"
        got = (found["rmse_mm"], found["mean_mm"], found["max_mm"])
        np.testing.assert_allclose(got, registered, rtol=0.01)
