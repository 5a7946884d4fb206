"""The residual map as a user meets it: ``station calibrate`` stores it beside the corrected table
(``[map]``, ``T.map.npz``) and reports it, ``station verify`` judges the table plus the map, a map
file missing or of another calibration is bad input; a simulated drawstring cell whose robot carries
``UR10_LIKE``'s unmodelled error, and one without."""

import dataclasses
import json
import shutil

import numpy as np
import pytest
import tomli_w
import tomllib

import configs
from sim_fixtures.scenario import setup_dict
from sim_fixtures.unmodelled import UR10_LIKE
from sim_fixtures.world import World
from station.cli import main
from station.formats.plan import Plan
from station.formats.samples import load_samples
from station.formats.tables import load_map, load_robot, load_setup
from station.jobs.correction import offline_correction


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def cell_files(folder, unmodelled, seed: int = 0):
    """A cell's robot, setup, 70 contacts a line and 20 new ones a line (the hold-out) as files."""
    world = dataclasses.replace(World.create(seed), unmodelled=unmodelled)
    rng = np.random.default_rng(1000 + seed)
    files = {name: folder / name for name in ("robot.toml", "setup.toml", "samples.csv", "holdout.csv")}
    files["robot.toml"].write_text(configs.path("robots/hsr_jr680.toml").read_text())
    world.sample_set(70, rng).to_csv(files["samples.csv"])
    world.sample_set(20, rng).to_csv(files["holdout.csv"])
    files["setup.toml"].write_text(tomli_w.dumps(setup_dict(world, rng)))
    return files, world


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The unmodelled cell calibrated by default: its files, the corrected table and report."""
    folder = tmp_path_factory.mktemp("mapped")
    files, world = cell_files(folder, UR10_LIKE)
    out, rep = folder / "corrected.toml", folder / "report.json"
    argv = ["calibrate", files["samples.csv"], "--robot", files["robot.toml"], "--setup", files["setup.toml"]]
    code = main([str(a) for a in [*argv, "--out", out, "--report", rep, "--no-history"]])
    assert code == 0
    return files, out, json.loads(rep.read_text()), world


def verify(capsys, files, table, folder):
    """``station verify`` of the hold-out contacts with ``table``: exit code, V.json, stdout."""
    v = folder / f"{table.stem}.V.json"
    argv = ["verify", files["holdout.csv"], "--table", table, "--robot", files["robot.toml"]]
    code, out, err = _cli(capsys, *argv, "--setup", files["setup.toml"], "--report", v, "--no-history")
    return code, (json.loads(v.read_text()) if v.exists() else None), out + err


def test_calibrate_stores_the_map_beside_the_table_and_reports_it(calibrated, capsys):
    files, out, report, _ = calibrated
    table = tomllib.loads(out.read_text())
    assert table["map"]["file"] == "corrected.map.npz"
    assert (out.parent / "corrected.map.npz").is_file()
    assert table["map"]["rows"] == 210
    m = report["map"]
    assert m["used"] is True and m["rows"] == 210
    assert 0.3 < m["explained"] <= 1.0
    assert m["shared_mm"] is None or m["shared_mm"] > 0
    assert "with the map" in m["why"]


def test_verify_judges_the_table_plus_the_map(calibrated, capsys, tmp_path):
    """New contacts among the measured ones: with the map they leave what an unchanged robot
    leaves (the verdict holds, V.json says the map was judged); the same table without its [map]
    cannot be judged on them (they leave an error no table expresses: refused, or drifted)."""
    files, out, _, _ = calibrated
    code, with_map, text = verify(capsys, files, out, tmp_path)
    assert code == 0 and with_map["verdict"] == "holds", text
    assert with_map["map"]["judged"] is True and with_map["map"]["predicted_rmse_mm"] > 0.05
    assert "judged with the table's residual map" in text
    alone = tmp_path / "alone.toml"
    table = tomllib.loads(out.read_text())
    del table["map"]
    alone.write_text(tomli_w.dumps(table))
    code, without, text = verify(capsys, files, alone, tmp_path)
    assert code in (2, 3), text
    assert without is None or ("map" not in without and without["rmse_mm"] > with_map["rmse_mm"])


def test_a_map_file_missing_or_of_another_calibration_is_bad_input(calibrated, capsys, tmp_path):
    files, out, _, _ = calibrated
    table = tmp_path / "corrected.toml"
    shutil.copy(out, table)
    code, _, text = verify(capsys, files, table, tmp_path)
    assert code == 2 and "corrected.map.npz" in text and "map.file" in text
    (tmp_path / "corrected.map.npz").write_bytes(b"not this one")
    code, _, text = verify(capsys, files, table, tmp_path)
    assert code == 2 and "sha256" in text and len(text.strip().splitlines()) == 1


def test_no_map_writes_the_table_alone(tmp_path, capsys):
    """``--no-map``: no [map], no map file, REPORT.json says why; a cell without unmodelled error
    keeps its map off by itself and writes no map file either."""
    files, _ = cell_files(tmp_path, None, seed=3)
    argv = ["calibrate", files["samples.csv"], "--robot", files["robot.toml"], "--setup", files["setup.toml"]]
    for flag, why in (("--no-map", "--no-map"), ("--no-history", "no clear gain")):
        out, rep = tmp_path / "t.toml", tmp_path / "r.json"
        code, text, _ = _cli(capsys, *argv, "--out", out, "--report", rep, "--no-history", flag)
        assert code == 0
        assert "map" not in tomllib.loads(out.read_text())
        assert not (tmp_path / "t.map.npz").exists()
        report = json.loads(rep.read_text())["map"]
        assert report["used"] is False and why in report["why"]
        assert "residual map: off" in text


def nominal_contacts(world, n: int = 15):
    """Joints [deg] at which the nominal model touches each of the cell's lines ``n`` times (a
    program written with it), and their lines."""
    nominal = world.nominal
    drawn = World(nominal, nominal, world.anchor_mm, world.length_offset_mm, world.lines)
    return drawn.line_configurations(n, np.random.default_rng(2))


def test_corrected_contacts_land_closer_to_the_edge_with_the_map(calibrated):
    """A program of contacts written with the nominal model, corrected by the table (its frame
    registered by the measured lines, as ``station program --table T --session S``): the simulated
    true robot, which carries the unmodelled error, lands them on the edges; the dial reads the miss
    across each edge. With the table's map the miss is at most 3/4 of the table's alone."""
    files, out, _, world = calibrated
    q_plan, lines = nominal_contacts(world)
    plan = Plan(np.arange(len(lines)), lines, q_plan)
    table, robot = load_robot(out), load_robot(files["robot.toml"])
    setup, samples = load_setup(files["setup.toml"]), load_samples(files["samples.csv"])
    fixes = {name: offline_correction(plan, robot, table, setup, samples, found) for name, found in
             (("table", None), ("map", load_map(table, out)))}  # fmt: skip
    ok = fixes["table"].ok & fixes["map"].ok  # a few near the wrist singularity keep their joints
    assert ok.sum() >= 0.8 * len(ok)
    miss = {}
    for name, fix in fixes.items():
        q_true, reached = world.landing(fix.q_deg[ok], lines[ok])
        assert reached.all()
        miss[name] = float(np.sqrt(np.mean(world.true_dial_mm(q_true, lines[ok]) ** 2)))
    assert miss["map"] < 0.75 * miss["table"], miss


def test_compensate_adds_the_maps_prediction_and_counts_its_variance(calibrated, capsys, tmp_path):
    """``station compensate`` of the nominal contacts with the table and its map: the report says
    the map was used, the targets move by the map's prediction beyond the table's shift, and the
    predicted accuracy near the measured poses is tighter than the table's alone."""
    files, out, _, world = calibrated
    q_plan, _ = nominal_contacts(world)
    program = tmp_path / "program.csv"
    rows = [",".join([str(i), *(f"{v:.6f}" for v in q)]) for i, q in enumerate(q_plan)]
    program.write_text("\n".join(["step," + ",".join(f"q{i}_deg" for i in range(1, 7)), *rows]) + "\n")
    alone = tmp_path / "alone.toml"
    table = tomllib.loads(out.read_text())
    del table["map"]
    alone.write_text(tomli_w.dumps(table))
    reports, texts = {}, {}
    for name, t in (("map", out), ("table", alone)):
        rep, compensated = tmp_path / f"{name}.json", tmp_path / f"{name}.csv"
        argv = ["compensate", program, "--table", t, "--robot", files["robot.toml"], "--out", compensated]
        code, texts[name], _ = _cli(capsys, *argv, "--report", rep)
        assert code == 0, texts[name]
        reports[name] = json.loads(rep.read_text())
    assert reports["map"]["map"] == {"used": True} and "map" not in reports["table"]
    assert "residual map" in texts["map"] and "residual map" not in texts["table"]
    assert reports["map"]["predicted"]["rmse_mm"] < reports["table"]["predicted"]["rmse_mm"]
    assert reports["map"]["shift_mm"]["rms"] != reports["table"]["shift_mm"]["rms"]


@pytest.mark.parametrize("fmt", ["urdf", "dh-csv"])
def test_export_says_in_one_line_that_the_map_is_left_out(calibrated, capsys, tmp_path, fmt):
    files, out, _, _ = calibrated
    code, text, err = _cli(capsys, "export", out, "--format", fmt, "--out", tmp_path / "x")
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "residual map" in lines[0] and "corrected.map.npz" in lines[0]
    alone = tmp_path / "alone.toml"
    table = tomllib.loads(out.read_text())
    del table["map"]
    alone.write_text(tomli_w.dumps(table))
    code, _, err = _cli(capsys, "export", alone, "--format", fmt, "--out", tmp_path / "y")
    assert code == 0 and err == ""
