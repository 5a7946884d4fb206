"""``station plan --near PROGRAM.csv``: the plan's contacts near the program's poses, the table
still determined, and one-line errors for a bad program."""

import csv
import json

import numpy as np
import pytest
import tomli_w

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


def test_the_program_is_read_in_the_controllers_joints(tmp_path):
    """A KUKA-like ``[controller]`` in the robot file: the same program in the controller's joints
    gives the same plan as in the model's under the shipped file."""
    sign, offset = np.array([-1, 1, 1, -1, 1, -1]), np.array([0.0, -90.0, 90.0, 0.0, 0.0, 0.0])
    robot = tmp_path / "kuka.toml"
    controller = {"joint_sign": sign.tolist(), "joint_offset_deg": offset.tolist()}
    robot.write_text(ROBOT.read_text() + "\n" + tomli_w.dumps({"controller": controller}))
    q = program_deg()
    plans = []
    for name, robot_file, program in (("model", ROBOT, q), ("kuka", robot, sign * (q - offset))):
        argv = plan_argv(tmp_path, write_program(tmp_path / f"{name}.csv", program))
        argv[argv.index("--robot") + 1] = str(robot_file)
        argv[argv.index("--out") + 1] = str(tmp_path / f"{name}-plan.csv")
        assert cli.main(argv + ["--near-poses", "20"]) == 0
        plans.append(load_plan(tmp_path / f"{name}-plan.csv"))
    assert np.allclose(plans[0].q_deg, plans[1].q_deg, atol=1e-4)
