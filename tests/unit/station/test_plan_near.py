"""``station plan --near PROGRAM.csv``: the plan's contacts near the program's poses, the table
still determined, and one-line errors for a bad program."""

import csv
import json

import numpy as np
import pytest

import configs
from calib.near import NEAR_DEG, chord_deg
from sim_fixtures.world import World
from station import cli
from station.formats.plan import load_plan

ROBOT, SETUP = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")
HEADER = ["name", *(f"q{i}_deg" for i in range(1, 7))]


def write_program(path, q_deg, header=HEADER):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows([f"p{k}", *(f"{v:.4f}" for v in q)] for k, q in enumerate(q_deg))
    return path


def program_deg(seed: int = 5) -> np.ndarray:
    """Poses a few degrees (joints 1-3) and more (the wrist) off contacts with the sim cell's lines."""
    rng = np.random.default_rng(seed)
    q, _ = World.create(0).line_configurations(6, rng)
    return q + np.hstack([rng.uniform(-3, 3, (len(q), 3)), rng.uniform(-10, 10, (len(q), 3))])


def plan_argv(tmp_path, program):
    argv = ["plan", "--robot", str(ROBOT), "--setup", str(SETUP), "--no-suggest", "--readings", "1"]
    return argv + ["--near", str(program), "--out", str(tmp_path / "plan.csv")]


def test_near_adds_contacts_near_the_program_and_keeps_the_table_determined(tmp_path, capsys):
    q_program = program_deg()
    program = write_program(tmp_path / "program.csv", q_program)
    argv = plan_argv(tmp_path, program) + ["--near-poses", "30", "--report", str(tmp_path / "r.json")]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    report, plan = json.loads((tmp_path / "r.json").read_text()), load_plan(tmp_path / "plan.csv")
    n_mcs, near = report["selection"]["n"], report["near"]
    assert len(plan) == n_mcs + 30 and near["poses"] == 30
    added = np.radians(plan.q_deg[n_mcs:])
    assert chord_deg(added, np.radians(q_program)).max() <= NEAR_DEG
    assert near["covered"] == near["coverable"] >= 0.8  # every pose a contact is near has one planned
    # the MCS plan's rows determine the table: the whole plan promises no worse than all candidates x 2
    assert (
        report["predicted"]["plan"]["predicted_rmse_mm"]
        < 2 * report["predicted"]["all_candidates"]["predicted_rmse_mm"]
    )
    assert f"plan ({len(plan)} poses)" in out and f"near {program}: 30 of" in out


def errors_of(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if not ln.startswith("... ")]


def test_a_program_far_from_every_line_is_a_one_line_error(tmp_path, capsys):
    q = program_deg()
    q[:, 0] += 180.0  # the arm turned away from the gauge lines
    argv = plan_argv(tmp_path, write_program(tmp_path / "far.csv", q))
    assert cli.main(argv) == 2
    (err,) = errors_of(capsys)
    assert err.startswith("station: error: no gauge line within reach of the program's poses: ")
    assert str(tmp_path / "far.csv") in err and not (tmp_path / "plan.csv").exists()


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda rows: [r[:-1] for r in rows], "far.csv: missing column q6_deg"),
        (
            lambda rows: rows[:2] + [[*rows[2][:3], "abc", *rows[2][4:]]],
            "far.csv: row 1 (line 3): q3_deg: 'abc'",
        ),
    ],
)
def test_a_bad_program_is_a_one_line_error(tmp_path, capsys, edit, expected):
    rows = [HEADER, *([f"p{k}", *(f"{v:.4f}" for v in q)] for k, q in enumerate(program_deg()))]
    with open(tmp_path / "far.csv", "w", newline="") as f:
        csv.writer(f).writerows(edit(rows))
    assert cli.main(plan_argv(tmp_path, tmp_path / "far.csv")) == 2
    (err,) = errors_of(capsys)
    assert expected in err and not (tmp_path / "plan.csv").exists()
