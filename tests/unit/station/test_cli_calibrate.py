"""`station calibrate` as a user runs it: outputs on success, one-line errors (exit 2) on bad input."""

import json

import pytest
import tomli_w
import tomllib

from station.cli import main


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_calibrate_writes_table_and_report(three_lines, tmp_path, capsys):
    sc = three_lines
    out, rep = tmp_path / "corrected.toml", tmp_path / "report.json"
    code, text, _ = _cli(
        capsys,
        "calibrate",
        sc.samples,
        "--robot",
        sc.robot,
        "--setup",
        sc.setup,
        "--out",
        out,
        "--holdout",
        sc.holdout,
        "--report",
        rep,
    )
    assert code == 0
    assert "holdout after" in text
    report = json.loads(rep.read_text())
    for key in (
        "kind",
        "method",
        "before",
        "after",
        "anchor_mm",
        "length_offset_mm",
        "lines",
        "identified",
        "held",
        "parameters",
        "downweighted",
        "workspace",
        "warnings",
        "iterations",
        "time_s",
    ):
        assert key in report, key
    # The corrected table reads back as a robot model and calibrates again.
    code, _, _ = _cli(
        capsys, "calibrate", sc.samples, "--robot", out, "--setup", sc.setup, "--out", tmp_path / "again.toml"
    )
    assert code == 0


def _lines(path):
    return path.read_text().splitlines()


CSV_CASES = {
    "missing column": (lambda h, rows: (h.replace("q3_deg", "q3"), rows), "missing column q3_deg"),
    "text in a number": (
        lambda h, rows: (h, [rows[0].replace(rows[0].split(",")[4], "abc", 1)] + rows[1:]),
        "row 0 (line 2): q3_deg: 'abc' is not a finite number",
    ),
    "NaN in a number": (
        lambda h, rows: (h, rows[:5] + [rows[5].replace(rows[5].split(",")[-2], "nan")] + rows[6:]),
        "row 5 (line 7): length_mm: 'nan' is not a finite number",
    ),
    "empty file": (lambda h, rows: ("", []), "empty file"),
    "fewer samples than parameters": (lambda h, rows: (h, rows[:10]), "10 samples cannot determine"),
    "both length and position": (
        lambda h, rows: (h + ",x_mm,y_mm,z_mm", [r + ",1,2,3" for r in rows]),
        "has both length_mm and x_mm",
    ),
    "neither length nor position": (
        lambda h, rows: (h.replace("length_mm", "len"), rows),
        "has neither length_mm",
    ),
}


@pytest.mark.parametrize("case", CSV_CASES)
def test_bad_samples_csv(case, three_lines, tmp_path, capsys):
    edit, message = CSV_CASES[case]
    header, *rows = _lines(three_lines.samples)
    header, rows = edit(header, rows)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join([header, *rows]) + ("\n" if header else ""))
    out = tmp_path / "out.toml"
    code, _, err = _cli(
        capsys, "calibrate", bad, "--robot", three_lines.robot, "--setup", three_lines.setup, "--out", out
    )
    assert code == 2
    assert err.count("\n") == 1 and str(bad) in err and message in err
    assert not out.exists()


def test_robot_with_five_joints(three_lines, tmp_path, capsys):
    text = three_lines.robot.read_text()
    robot = tmp_path / "robot.toml"
    robot.write_text(text[: text.rindex("[[joints]]")])
    code, _, err = _cli(
        capsys,
        "calibrate",
        three_lines.samples,
        "--robot",
        robot,
        "--setup",
        three_lines.setup,
        "--out",
        tmp_path / "o.toml",
    )
    assert code == 2 and str(robot) in err and "joints: expected 6 joints, got 5" in err
    assert not (tmp_path / "o.toml").exists()


def test_setup_anchor_with_two_numbers(three_lines, tmp_path, capsys):
    setup = tmp_path / "setup.toml"
    data = tomllib.loads(three_lines.setup.read_text())
    data["drawstring"]["anchor_mm"] = [1.0, 2.0]
    setup.write_text(tomli_w.dumps(data))
    code, _, err = _cli(
        capsys,
        "calibrate",
        three_lines.samples,
        "--robot",
        three_lines.robot,
        "--setup",
        setup,
        "--out",
        tmp_path / "o.toml",
    )
    assert code == 2 and "drawstring.anchor_mm: expected 3 numbers, got 2" in err and str(setup) in err
    assert not (tmp_path / "o.toml").exists()


def test_path_that_does_not_exist(three_lines, tmp_path, capsys):
    code, _, err = _cli(
        capsys,
        "calibrate",
        three_lines.samples,
        "--robot",
        tmp_path / "no.toml",
        "--setup",
        three_lines.setup,
        "--out",
        tmp_path / "o.toml",
    )
    assert code == 2 and "no.toml: no such file" in err


def test_unwritable_output_folder(three_lines, tmp_path, capsys):
    code, _, err = _cli(
        capsys,
        "calibrate",
        three_lines.samples,
        "--robot",
        three_lines.robot,
        "--setup",
        three_lines.setup,
        "--out",
        tmp_path / "missing" / "o.toml",
    )
    assert code == 2 and "does not exist" in err


def _report(capsys, sc, tmp_path, method):
    rep = tmp_path / f"{method}.json"
    argv = ["calibrate", sc.samples, "--robot", sc.robot, "--setup", sc.setup, "--holdout", sc.holdout]
    code, _, _ = _cli(
        capsys, *argv, "--out", tmp_path / f"{method}.toml", "--method", method, "--report", rep
    )
    assert code == 0
    return json.loads(rep.read_text())


def test_a_baseline_method_calibrates_through_the_same_command(three_lines, tmp_path, capsys):
    # Gauss-Newton from the common start reaches the same optimum as LMLC on clean data.
    lmlc, gn = (_report(capsys, three_lines, tmp_path, m) for m in ("lmlc", "gn"))
    assert gn["method"] == "gn" and gn["identified"] == lmlc["identified"]
    assert gn["after"]["holdout"]["rmse_mm"] < 1.2 * lmlc["after"]["holdout"]["rmse_mm"]
    assert not gn["warnings"]


def test_a_baseline_that_stops_short_says_so(three_lines, tmp_path, capsys):
    # PSO within its default budget stays far from the optimum (benchmarks/RESULTS-compare.md).
    pso = _report(capsys, three_lines, tmp_path, "pso")
    assert any("stopped short of the least-squares optimum" in w for w in pso["warnings"])


@pytest.mark.parametrize(
    "with_setup, flags, message",
    [
        (True, ["--method", "mcs-lmlc", "--select", "5"], "--select 5: must lie between the 35 unknowns"),
        (True, ["--select", "72"], "--select 72: selecting configurations needs --method mcs-lmlc"),
        (False, [], "samples.csv: a drawstring set needs --setup"),
    ],
)
def test_a_bad_parameter_is_named_by_its_flag(three_lines, tmp_path, capsys, with_setup, flags, message):
    """The service names its parameters (select, method, setup); the user reads the flags."""
    sc, out = three_lines, tmp_path / "o.toml"
    setup = ["--setup", sc.setup] if with_setup else []
    code, _, err = _cli(capsys, "calibrate", sc.samples, "--robot", sc.robot, *setup, "--out", out, *flags)
    assert code == 2 and err.count("\n") == 1 and message in err
    assert not out.exists()


def _edit_toml(path, out, edit):
    data = tomllib.loads(path.read_text())
    edit(data)
    out.write_text(tomli_w.dumps(data))
    return out


def _edit_cell(path, out, row, column, value):
    header, *rows = _lines(path)
    cells = rows[row].split(",")
    cells[header.split(",").index(column)] = value
    rows[row] = ",".join(cells)
    out.write_text("\n".join([header, *rows]) + "\n")
    return out


def _set(*keys, value):
    def edit(data):
        for key in keys[:-1]:
            data = data[key]
        data[keys[-1]] = value

    return edit


# Values that parse but that the maths cannot take (issue 15: the first four ended in tracebacks):
# (input edited, how, the one line's key and reason).
VALUE_CASES = {
    "NaN in the setup": ("setup", _set("drawstring", "length_offset_mm", value=float("nan")),
                         "drawstring.length_offset_mm: Input should be a finite number"),
    "1e308 in a samples cell": ("samples", (3, "length_mm", "1e308"),
                                "row 3 (line 5): length_mm: '1e308' is outside -100000 .. 100000 mm"),
    "NaN in the robot": ("robot", _set("joints", 1, "a_mm", value=float("nan")),
                         "joints.1.a_mm: Input should be a finite number"),
    "inf in a hold-out cell": ("holdout", (2, "line", "inf"),
                               "row 2 (line 4): line: 'inf' is not a line id (a whole number 0 .. 1e+09)"),
    "a 1e308 mm length": ("robot", _set("joints", 2, "d_mm", value=1e308),
                          "joints.2.d_mm: Input should be less than or equal to 100000"),
    "a zero dial axis": ("setup", _set("lines", 1, "dial_axis", value=[0.0, 0.0, 0.0]),
                         "lines.1.dial_axis: must be a direction, not the zero vector"),
    "a zero sigma": ("setup", _set("drawstring", "sigma_mm", value=0.0),
                     "drawstring.sigma_mm: Input should be greater than or equal to 0.000001"),
    "joint limits the wrong way round": ("robot", _set("joints", 4, "q_min_deg", value=200.0),
                                         "joints.4: q_min_deg 200 must be below q_max_deg 135"),
    "a line placed twice": ("setup", _set("lines", 2, "id", value=0),
                            "(top level): line id 0 appears twice in [[lines]]"),
    "a joint reading of ten thousand degrees": ("samples", (0, "q6_deg", "1e4"),
                                                "row 0 (line 2): q6_deg: '1e4' is outside -3600 .. 3600 deg"),
}  # fmt: skip


@pytest.mark.parametrize("case", VALUE_CASES)
def test_a_value_the_maths_cannot_take_is_refused_naming_file_and_key(case, three_lines, tmp_path, capsys):
    which, edit, message = VALUE_CASES[case]
    files = {"samples": three_lines.samples, "robot": three_lines.robot, "setup": three_lines.setup}
    files["holdout"] = three_lines.holdout
    source = files[which]
    bad = tmp_path / f"bad{source.suffix}"
    edited = _edit_cell(source, bad, *edit) if isinstance(edit, tuple) else _edit_toml(source, bad, edit)
    files[which] = edited
    out, report = tmp_path / "o.toml", tmp_path / "r.json"
    code, _, err = _cli(
        capsys, "calibrate", files["samples"], "--robot", files["robot"], "--setup", files["setup"],
        "--holdout", files["holdout"], "--out", out, "--report", report,
    )  # fmt: skip
    assert code == 2
    assert err == f"station: error: {bad}: {message}\n"
    assert not out.exists() and not report.exists()
