"""``station report``: the calibration certificate states every figure of the report it is made
from, says what none of its sources carries, shows names as text, and refuses what is no report
(exit 2, one line, nothing written). The page in a browser: ``tests/system/test_certificate.py``."""

import base64
import json
from html.parser import HTMLParser

import pytest
import tomli_w

from station.cli import main
from station.formats.base import read_toml

HOSTILE = '<script>alert("x")</script> & <b>'
MATHTEXT = r"J1.$\notacommand$_mm"  # what matplotlib would parse as mathtext, and fail on


class Page(HTMLParser):
    """The page's text, its elements' names and every ``src`` / ``href``."""

    def __init__(self, text: str):
        super().__init__()
        self.tags, self.links, self.parts = [], [], []
        self.feed(text)
        self.text = " ".join(" ".join(self.parts).split())

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.links += [v for k, v in attrs if k in ("src", "href")]

    def handle_data(self, data):
        self.parts.append(data)


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def calibrated(three_lines, tmp_path_factory):
    """A calibration of the three-line cell with a hold-out, its robot carrying a serial, and a
    verification of its table on the hold-out rows: reports and history records."""
    folder = tmp_path_factory.mktemp("cert")
    db = folder / "history.sqlite"
    robot = folder / "robot.toml"
    robot.write_text(tomli_w.dumps({**read_toml(three_lines.robot), "serial": "JR680-0042"}))
    sc, table = three_lines, folder / "corrected.toml"
    common = ["--robot", robot, "--setup", sc.setup, "--db", db]
    calibrate = ["calibrate", sc.samples, *common, "--out", table, "--holdout", sc.holdout]
    assert main([str(a) for a in (*calibrate, "--report", folder / "report.json")]) == 0
    verify = ["verify", sc.holdout, "--table", table, *common, "--report", folder / "verify.json"]
    assert main([str(a) for a in verify]) in (0, 3)  # holds or drifted: a verdict either way
    return folder, db, sc


def _certificate(capsys, report, out, db) -> Page:
    code, printed, err = _run(capsys, "report", report, "--out", out, "--db", db)
    assert code == 0, err
    assert printed.strip().endswith(f"-> {out}")
    return Page(out.read_text())


def _pictures(page: Page) -> list[bytes]:
    """Every picture's PNG bytes; each must be embedded, none fetched."""
    pngs = []
    for link in page.links:
        assert link.startswith("data:image/png;base64,"), link[:60]
        pngs.append(base64.b64decode(link.split(",", 1)[1]))
    assert all(p.startswith(b"\x89PNG\r\n\x1a\n") for p in pngs)
    return pngs


def test_the_calibration_certificate_states_every_figure_of_its_report(calibrated, tmp_path, capsys):
    folder, db, sc = calibrated
    report = json.loads((folder / "report.json").read_text())
    page = _certificate(capsys, folder / "report.json", tmp_path / "c.html", db)
    text = page.text
    for fact in ("HSR-JR680", "JR680-0042", "standard Denavit-Hartenberg (dh)", report["station_version"]):
        assert fact in text
    assert report["created_utc"][:10] in text and report["samples"] in text
    assert f"({len(sc.train.line)} rows)" in text
    sigma = read_toml(sc.setup)["drawstring"].get("sigma_mm", 0.02)
    assert f"{sigma:g} mm per reading" in text
    for when in ("before", "after"):
        for part in ("train", "holdout"):
            m = report[when][part]
            assert f"{m['rmse_mm']:.3f} mm {m['mean_mm']:.3f} mm {m['max_mm']:.3f} mm" in text
    for line in report["lines"]:
        m = f"{line['rmse_mm']:.3f} mm {line['mean_mm']:.3f} mm {line['max_mm']:.3f} mm"
        assert f"{line['id']} {m}" in text
    ws = report["workspace"]
    assert f"{ws['predicted_rmse_mm']:.3f} mm RMS (95 %: below {ws['predicted_rmse_95_mm']:.3f} mm)" in text
    for name, p in report["parameters"].items():
        unit = name.rpartition("_")[2]
        assert f"{name} {unit} {p['nominal']:.5g} {p['value']:.5g} {p['delta']:+.5g}" in text
        assert f"{p['sigma']:.5g}" in text
    for held in report["held"]:
        assert held["param"] in text and " ".join(held["reason"].split()) in text
    assert f"Fit check: {report['fit_check']['verdict']}" in text
    assert f"Next: {report['next']}" in text
    assert "History of robot JR680-0042" in text and "#1" in text and "#2" in text
    assert len(_pictures(page)) == 5  # workspace, before/after, per line, parameters, history
    assert "script" not in page.tags


def test_the_verification_certificate_states_its_verdict_and_lines(calibrated, tmp_path, capsys):
    folder, db, _ = calibrated
    report = json.loads((folder / "verify.json").read_text())
    page = _certificate(capsys, folder / "verify.json", tmp_path / "v.html", db)
    assert f"Verification: {report['verdict']}" in page.text
    assert f"{report['rmse_mm']:.3f} mm RMS" in page.text
    assert f"({report['rows']} rows)" in page.text
    for line in report["lines"]:
        assert f"{line['id']} {line['rows']} {line['rmse_mm']:.3f} mm" in page.text
    assert "Verification certificate" in page.text and "corrected table, calibrated" in page.text
    assert len(_pictures(page)) == 2  # per line, history


def test_a_name_from_a_report_is_text(calibrated, tmp_path, capsys):
    folder, db, _ = calibrated
    report = json.loads((folder / "report.json").read_text())
    report["robot"] = {"name": HOSTILE, "serial": None}
    report["warnings"] = [HOSTILE]
    report["held"] = [{"param": "J1.theta_deg", "reason": HOSTILE}]
    report["parameters"][MATHTEXT] = {"value": 1.0, "sigma": 0.1, "nominal": 0.0, "delta": 1.0}
    report["lines"][0]["id"] = MATHTEXT
    forged = tmp_path / "forged.json"
    forged.write_text(json.dumps(report))
    page = _certificate(capsys, forged, tmp_path / "c.html", db)
    html = (tmp_path / "c.html").read_text()
    assert HOSTILE not in html and "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt; &amp; &lt;b&gt;" in html
    assert "script" not in page.tags and page.text.count(HOSTILE) >= 4  # title, header, robot, warning, held
    assert page.text.count(MATHTEXT) == 2  # the parameter and the line, drawn in their pictures too


def test_what_no_source_carries_is_said_unknown(calibrated, tmp_path, capsys):
    folder, _, _ = calibrated
    report = json.loads((folder / "report.json").read_text())
    report["robot"] = {"name": "HSR-JR680", "serial": None}  # made before the convention was recorded
    report.update(setup=str(tmp_path / "gone.toml"), samples=str(tmp_path / "gone.csv"))
    old = tmp_path / "old.json"
    old.write_text(json.dumps(report))
    text = _certificate(capsys, old, tmp_path / "c.html", tmp_path / "none.sqlite").text
    assert "Convention not stated in the report" in text
    assert f"unknown: the report names its setup '{tmp_path / 'gone.toml'}', which is no file here" in text
    assert "(row count unknown)" in text and "not stated (the robot file gives none)" in text
    assert f"No records of robot HSR-JR680 in the history database {tmp_path / 'none.sqlite'}" in text


@pytest.mark.parametrize(
    "content, says",
    [
        (None, "no such file"),
        ("{not json", "not a report: not JSON"),
        ("[1, 2]", "not a report of station calibrate (no parameters) or station verify (no verdict)"),
        (json.dumps({"rows": 3}), "not a report of station calibrate"),
        (json.dumps({"verdict": "holds"}), "(a verification report): rmse_mm: Field required"),
        (json.dumps({"parameters": [], "kind": "drawstring"}), "(a calibration report): method: Field"),
    ],
)
def test_what_is_no_report_is_refused_in_one_line(tmp_path, capsys, content, says):
    given = tmp_path / "given.json"
    if content is not None:
        given.write_text(content)
    out = tmp_path / "c.html"
    code, printed, err = _run(capsys, "report", given, "--out", out)
    assert code == 2 and printed == ""
    assert err.count("\n") == 1 and err.startswith(f"station: error: {given}") and says in err
    assert list(tmp_path.iterdir()) == ([given] if content is not None else [])


def test_an_unwritable_out_is_refused_before_any_work(calibrated, tmp_path, capsys):
    folder, _, _ = calibrated
    out = tmp_path / "missing" / "c.html"
    code, _, err = _run(capsys, "report", folder / "report.json", "--out", out)
    assert code == 2 and err == f"station: error: --out {out}: folder {out.parent} does not exist\n"
    assert not out.parent.exists()


def test_a_certificate_already_there_stays_when_the_report_is_bad(tmp_path, capsys):
    out = tmp_path / "c.html"
    out.write_text("the certificate filed last year")
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    assert _run(capsys, "report", bad, "--out", out)[0] == 2
    assert out.read_text() == "the certificate filed last year"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json", "c.html"]


def test_one_sessions_records_are_drawn_over_an_hour_not_years(monkeypatch, tmp_path):
    from station.view import plots

    drawn = []
    monkeypatch.setattr(plots.plt, "close", drawn.append)
    records = [
        {"id": k, "time_utc": f"2026-11-27T03:49:1{k}+00:00", "command": "verify", "verdict": v, "rmse_mm": r}
        for k, (v, r) in enumerate((("holds", 0.016), ("drifted", 0.148)))
    ]
    plots.history_figure("R1", records, [], tmp_path / "h.png")
    low, high = drawn[0].axes[0].get_xlim()  # days
    assert 0.5 / 24 < high - low <= 1 / 24 + 1e-9


def test_a_setup_no_longer_readable_leaves_the_noise_unknown(calibrated, tmp_path, capsys):
    folder, db, _ = calibrated
    report = json.loads((folder / "report.json").read_text())
    broken = tmp_path / "setup.toml"
    broken.write_text("[drawstring\n")
    report["setup"] = str(broken)
    given = tmp_path / "r.json"
    given.write_text(json.dumps(report))
    text = _certificate(capsys, given, tmp_path / "c.html", db).text
    assert f"unknown: the setup the report names cannot be read now ({broken}: not valid TOML" in text
    assert "per reading" not in text


def test_only_the_latest_calibrations_moves_are_listed_earlier_ones_counted():
    """Three calibrations, J2.a_mm moving between each: the table lists the move into the latest
    (record 3), the one before is counted, not listed (a long history buried the latest)."""
    from station.history import moves
    from station.view.certificate import moves_block

    def record(k, a_mm):
        figures = {
            "parameters": {"J2.a_mm": {"value": a_mm, "sigma": 0.01}, "J3.a_mm": {"value": 5, "sigma": 1}}
        }
        return {
            "id": k,
            "time_utc": f"2026-11-2{k}T10:00:00+00:00",
            "command": "calibrate",
            "figures": figures,
        }

    found = [record(1, 900.0), record(2, 900.5), record(3, 901.25)]
    page = Page(moves_block(found, tuple(moves(found))))
    assert "Record #3 against the calibration before it." in page.text
    assert "J2.a_mm +0.75 mm 53.0" in page.text  # 0.75 mm over sqrt(2) x 0.01 mm
    assert "+0.5 mm" not in page.text
    assert "1 earlier move between older calibrations" in page.text
    steady = [record(1, 900.0), record(2, 900.5), record(3, 900.5)]
    assert (
        "None beyond 3 combined sigmas between records #2 and #3."
        in Page(moves_block(steady, tuple(moves(steady)))).text
    )
