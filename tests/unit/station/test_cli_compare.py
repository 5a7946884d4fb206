"""`station compare` as a user runs it: a line per method as it finishes, then the table."""

import json

from station.cli import main


def test_compare_says_each_method_as_it_finishes(three_lines, tmp_path, capsys):
    sc, report = three_lines, tmp_path / "compare.json"
    argv = ["compare", sc.samples, "--robot", sc.robot, "--setup", sc.setup, "--methods", "gn,lmlc"]
    assert main([str(a) for a in argv + ["--report", report]]) == 0
    out, err = capsys.readouterr()
    progress = err.splitlines()
    assert len(progress) == 3 and progress[0].startswith("... common start (setup fit, identification): ")
    methods = json.loads(report.read_text())["methods"]
    labels = ("M4 LS (Gauss-Newton) (1/2)", "M8 LMLC (2/2)")
    for line, label, row in zip(progress[1:], labels, methods, strict=True):
        assert line.startswith(f"... {label}: ") and f"training RMSE {row['train']['rmse_mm']:.4f} mm" in line
    assert out.splitlines()[0].startswith("method") and out.endswith(f"wrote {report}\n")
