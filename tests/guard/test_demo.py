"""``station demo`` as a newcomer runs it, against ``benchmarks/demo_baseline.json``: every target
measured, the hold-out and the true workspace error after calibration, the prediction honest, and
the verification's verdicts (the corrected table holds, the nominal one has drifted)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.guard

BASELINE = json.loads((Path(__file__).parents[2] / "benchmarks" / "demo_baseline.json").read_text())
FIGURES = re.compile(
    r"calibrate: lmlc +hold-out (?P<hold0>[\d.]+) -> (?P<hold1>[\d.]+) mm RMSE, "
    r"predicted workspace [\d.]+ mm \(95 %: (?P<bound>[\d.]+)\).*"
    r"true workspace error \(simulation, 1000 random poses\) "
    r"(?P<true0>[\d.]+) -> (?P<true1>[\d.]+) mm RMS"
)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "out"
    done = subprocess.run(
        [sys.executable, "-m", "station.cli", "demo", "--no-viewer", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=400,
    )
    return done, out


def test_the_demo_measures_every_target_and_calibrates_as_it_did(demo):
    done, _ = demo
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"done: all {BASELINE['targets']} targets measured" in done.stdout
    found = FIGURES.search(done.stdout)
    assert found, done.stdout[-3000:]
    figures = {k: float(v) for k, v in found.groupdict().items()}
    # before the calibration: the same simulated cell, to the last digit's rounding
    assert abs(figures["true0"] - BASELINE["true_before_mm"]) <= 0.002
    assert abs(figures["hold0"] - BASELINE["holdout_before_mm"]) <= 0.02
    assert figures["hold1"] <= BASELINE["holdout_after_max_mm"], figures
    assert figures["true1"] <= BASELINE["true_after_max_mm"], figures
    assert figures["true1"] <= figures["bound"], figures  # the 95 % bound holds the truth


def test_the_verification_holds_with_the_corrected_table_and_not_with_the_nominal(demo):
    done, out = demo
    assert done.returncode == 0
    for label, name in (("corrected", "verify.json"), ("nominal", "verify-nominal.json")):
        assert json.loads((out / name).read_text())["verdict"] == BASELINE["verdicts"][label], label
