"""Paths a user gives that a file system refuses or that are not UTF-8 text (issue 21, items 8-9):
one line and exit 2 before any work, or the work done with the path shown as it is named."""

import os

import pytest
import tomllib

from station.cli import main

LONG = "a" * 300  # one name of 300 bytes: Linux's file systems take 255


def _commands(sc, tmp_path):
    inputs = [sc.samples, "--robot", sc.robot, "--setup", sc.setup]
    calibrate = ["calibrate", *inputs, "--model", "geometric", "--out"]
    return {
        "calibrate --out": [*calibrate, tmp_path / LONG / "t.toml"],
        "calibrate --report": [*calibrate, tmp_path / "t.toml", "--report", tmp_path / LONG],
        "calibrate SAMPLES": ["calibrate", tmp_path / LONG, "--out", tmp_path / "t.toml"],
        "plan --out": ["plan", "--robot", sc.robot, "--setup", sc.setup, "--out", tmp_path / LONG],
        "export --out": ["export", sc.robot, "--format", "urdf", "--out", tmp_path / LONG],
        "sample --out": ["sample", "--out", tmp_path / LONG / "session"],
    }


COMMANDS = ["calibrate --out", "calibrate --report", "calibrate SAMPLES", "plan --out", "export --out"]


@pytest.mark.parametrize("command", [*COMMANDS, "sample --out"])
def test_a_name_too_long_for_a_file_system_is_one_line_and_exit_2(command, three_lines, tmp_path, capsys):
    code = main([str(a) for a in _commands(three_lines, tmp_path)[command]])
    out, err = capsys.readouterr()
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("station: error: ") and "aaaaaaaaaaaaaaaaaaaa...(300 bytes)" in err
    assert "a name in this path is 300 bytes long; at most 255" in err
    assert out == "" and list(tmp_path.iterdir()) == []


def test_a_name_near_the_limit_is_written_with_its_temporary_file(three_lines, tmp_path, capsys):
    name = "b" * 250  # the name fits; a temporary name built on it must too
    outputs = [tmp_path / f"{name}.toml", tmp_path / f"{name}.json", tmp_path / f"{name}.png"]
    code = main(
        ["calibrate", str(three_lines.samples), "--robot", str(three_lines.robot), "--setup"]
        + [str(three_lines.setup), "--model", "geometric", "--out", str(outputs[0])]
        + ["--report", str(outputs[1]), "--plot", str(outputs[2])]
    )
    capsys.readouterr()
    assert code == 0
    assert sorted(tmp_path.iterdir()) == sorted(outputs)


def test_calibrate_in_a_folder_whose_name_is_not_utf8(three_lines, tmp_path, capfdbinary):
    folder = tmp_path / os.fsdecode(b"cell-\xff")  # named on a system with another encoding
    folder.mkdir()
    samples = folder / "samples.csv"
    samples.write_bytes(three_lines.samples.read_bytes())
    table = folder / "t.toml"
    code = main(
        ["calibrate", str(samples), "--robot", str(three_lines.robot), "--setup", str(three_lines.setup)]
        + ["--model", "geometric", "--out", str(table), "--report", str(folder / "r.json")]
    )
    out, _ = capfdbinary.readouterr()
    assert code == 0
    assert out.splitlines()[-1].endswith(b"cell-\xff/t.toml, " + os.fsencode(folder / "r.json"))
    written = tomllib.loads(table.read_text())  # UTF-8 TOML, the name shown with \xNN
    assert written["calibration"]["samples"].endswith("cell-\\xff/samples.csv")
