"""``station demo`` end to end on a small plan (12 targets per gauge line instead of 70): simulated
devices, session, calibration against the simulated truth, report, corrected table, .rrd."""

from __future__ import annotations

import json

import numpy as np
from rerun.chunk import RrdReader

from station import cli
from station.formats.session_folder import load_session
from station.formats.tables import load_robot


def test_demo_writes_session_report_and_a_better_table(tmp_path, capsys):
    out = tmp_path / "demo"
    code = cli.main(["demo", "--out", str(out), "--no-viewer", "--targets-per-line", "12"])
    text = capsys.readouterr().out
    assert code == 0, text
    report = json.loads((out / "report.json").read_text())
    before, after = report["before"], report["after"]
    # The nominal table misses the simulated robot's errors by tenths of mm; the corrected one
    # leaves the drawstring noise (0.02 mm) on training and hold-out rows, within a factor 3.
    assert before["train"]["rmse_mm"] > 0.1 and before["holdout"]["rmse_mm"] > 0.1
    assert after["train"]["rmse_mm"] < 3 * 0.02 and after["holdout"]["rmse_mm"] < 3 * 0.02
    assert load_robot(out / "corrected.toml").calibration["n_samples"] == 36
    robot, setup, samples = load_session(out / "session")
    assert samples.exists() and setup.drawstring is not None
    truth = [line for line in text.splitlines() if line.startswith("true workspace error")]
    rms = [float(v) for v in truth[0].split(":")[1].replace("mm RMS", "").split("->")]
    assert rms[1] < rms[0] / 5
    entities = {c.entity_path for c in RrdReader(out / "session" / "session.rrd").stream().to_chunks()}
    assert {
        "/calibration/residual/lmlc/before",
        "/calibration/residual/lmlc/after",
        "/calibration/cost/lmlc",
        "/live/error",
    } <= entities
    assert np.isfinite(report["time_s"])
