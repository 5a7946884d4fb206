"""``station demo --sweep`` end to end: the demo's cell measured by sweeps (sweep plan, the
simulated robot sweeping, a streaming session, calibration against the simulated truth), within
two minutes of robot time, its predicted 95 % bound holding the true error."""

from __future__ import annotations

import re

import pytest

from station import cli
from station.formats.plan import load_plan
from station.formats.samples import load_samples

pytestmark = pytest.mark.system


def test_the_sweep_demo_calibrates_the_cell_within_two_minutes_of_robot_time(tmp_path, capsys):
    out = tmp_path / "demo"
    code = cli.main(["demo", "--sweep", "--no-viewer", "--seed", "1", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    robot = re.search(r"^robot: +([\d.]+) s of robot time", text, re.M)
    assert robot and float(robot[1]) <= 120.0, text
    plan = load_plan(out / "plan.csv")
    assert plan.is_sweep and len(set(plan.line.tolist())) == 3
    assert len(load_samples(out / "session" / "samples.csv")) > 1000  # streamed rows, not captures
    truth = re.search(r"true workspace error \(simulation, 1000 random poses\) ([\d.]+) -> ([\d.]+) mm", text)
    assert truth and float(truth[2]) < float(truth[1]) / 20, text
    bound = re.search(r"calibrate: lmlc .*predicted workspace [\d.]+ mm \(95 %: ([\d.]+)\)", text)
    assert bound and float(truth[2]) <= float(bound[1]), text  # the 95 % bound holds the truth
