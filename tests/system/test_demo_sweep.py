"""``station demo --sweep`` end to end: the demo's cell measured by sweeps (sweep plan, the
simulated robot sweeping, a streaming session, calibration against the simulated truth), within
two minutes of robot time, its predicted 95 % bound holding the true error, and the live view showing
each pass's rows and flagged rows on the view's timeline."""

from __future__ import annotations

import contextlib
import csv
import io
import re

import pytest
from rerun.chunk import RrdReader

from station import cli
from station.formats.plan import load_plan
from station.formats.samples import load_samples

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The sweep demo's folder and what it printed."""
    out = tmp_path_factory.mktemp("sweep") / "demo"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = cli.main(["demo", "--sweep", "--no-viewer", "--seed", "1", "--out", str(out)])
    assert code == 0, printed.getvalue()
    return out, printed.getvalue()


def test_the_sweep_demo_calibrates_the_cell_within_two_minutes_of_robot_time(demo):
    out, text = demo
    robot = re.search(r"^robot: +([\d.]+) s of robot time", text, re.M)
    assert robot and float(robot[1]) <= 120.0, text
    plan = load_plan(out / "plan.csv")
    assert plan.is_sweep and len(set(plan.line.tolist())) == 3
    assert len(load_samples(out / "session" / "samples.csv")) > 1000  # streamed rows, not captures
    truth = re.search(r"true workspace error \(simulation, 1000 random poses\) ([\d.]+) -> ([\d.]+) mm", text)
    assert truth and float(truth[2]) < float(truth[1]) / 20, text
    bound = re.search(r"calibrate: lmlc .*predicted workspace [\d.]+ mm \(95 %: ([\d.]+)\)", text)
    assert bound and float(truth[2]) <= float(bound[1]), text  # the 95 % bound holds the truth


def swept_points(rrd) -> tuple[dict[str, int], str]:
    """Points per sweep entity logged on the ``sample`` timeline (the one the view's layout shows),
    and the last progress text."""
    points, progress = {}, ""
    for chunk in RrdReader(rrd).stream().to_chunks():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if chunk.is_static or "sample" not in names:
            continue
        path = chunk.entity_path
        if path.startswith("/cell/sweep/"):
            column = batch.column(next(n for n in names if n.endswith("positions"))).to_pylist()
            points[path] = points.get(path, 0) + sum(len(v) for v in column)
        if path == "/progress":
            progress = batch.column(next(n for n in names if n.endswith("text"))).to_pylist()[-1][0]
    return points, progress


def test_the_live_view_shows_each_stored_pass_and_its_flagged_rows(demo):
    folder = demo[0] / "session"
    passes = sorted(set(load_plan(demo[0] / "plan.csv").sweep_pass.tolist()))
    points, progress = swept_points(folder / "session.rrd")
    rows = {p: n for p, n in points.items() if p.endswith("/rows")}
    assert set(rows) == {f"/cell/sweep/{p}/rows" for p in passes}
    assert sum(rows.values()) == len(load_samples(folder / "samples.csv"))
    with open(folder / "flagged.csv", newline="") as f:
        flagged = sum(1 for _ in csv.DictReader(f))
    assert sum(n for p, n in points.items() if p.endswith("/flagged")) == flagged
    assert points.get("/cell/sweep/now", 0) > 0  # the tool's trail as it slides
    assert progress.startswith(f"**{len(passes)} of {len(passes)} passes**"), progress
