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
    return files


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The unmodelled cell calibrated by default: its files, the corrected table and report."""
    folder = tmp_path_factory.mktemp("mapped")
    files = cell_files(folder, UR10_LIKE)
    out, rep = folder / "corrected.toml", folder / "report.json"
    argv = ["calibrate", files["samples.csv"], "--robot", files["robot.toml"], "--setup", files["setup.toml"]]
    code = main([str(a) for a in [*argv, "--out", out, "--report", rep, "--no-history"]])
    assert code == 0
    return files, out, json.loads(rep.read_text())


def verify(capsys, files, table, folder):
    """``station verify`` of the hold-out contacts with ``table``: exit code, V.json, stdout."""
    v = folder / f"{table.stem}.V.json"
    argv = ["verify", files["holdout.csv"], "--table", table, "--robot", files["robot.toml"]]
    code, out, err = _cli(capsys, *argv, "--setup", files["setup.toml"], "--report", v, "--no-history")
    return code, (json.loads(v.read_text()) if v.exists() else None), out + err


def test_calibrate_stores_the_map_beside_the_table_and_reports_it(calibrated, capsys):
    files, out, report = calibrated
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
    files, out, _ = calibrated
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
    files, out, _ = calibrated
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
    files = cell_files(tmp_path, None, seed=3)
    argv = ["calibrate", files["samples.csv"], "--robot", files["robot.toml"], "--setup", files["setup.toml"]]
    for flag, why in (("--no-map", "--no-map"), ("--no-history", "no gain")):
        out, rep = tmp_path / "t.toml", tmp_path / "r.json"
        code, text, _ = _cli(capsys, *argv, "--out", out, "--report", rep, "--no-history", flag)
        assert code == 0
        assert "map" not in tomllib.loads(out.read_text())
        assert not (tmp_path / "t.map.npz").exists()
        report = json.loads(rep.read_text())["map"]
        assert report["used"] is False and why in report["why"]
        assert "residual map: off" in text
