"""Speed of program compensation (issue 12 target: 10,000 rows in <= 1 s in-process), medians of one run.

    python benchmarks/compensate_speed.py [--rows 10000] [--repeats 7]

The calibrated robot is the simulated cell's true HSR-JR680 (seed 0: errors of a built arm, 4.9 mm
at the TCP); the program is ``--rows`` random configurations within the joint limits, the worst
case (a real program keeps away from singularities, where rows take the most Newton steps).
Timed: the maths alone (``calib.compensation.compensate``), and the whole job in-process (read
the program CSV, compensate, status texts, report with the predicted accuracy, the output CSV).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import timeit
from pathlib import Path

import numpy as np

from calib.compensation import Status, compensate
from sim_fixtures.world import World
from station.formats.program import load_program
from station.formats.tables import RobotFile
from station.jobs import compensate as compensation


def median_time(fn, repeats: int) -> float:
    return statistics.median(timeit.repeat(fn, number=1, repeat=repeats))


def robot_file(table_alpha_a_d_theta: np.ndarray, limits_deg: np.ndarray, covariance=None) -> RobotFile:
    """A robot file of a simulated robot's table (rows alpha_deg, a_mm, d_mm, theta_deg)."""
    joints = [
        {"alpha_deg": al, "a_mm": a, "d_mm": d, "theta_deg": th, "q_min_deg": lo, "q_max_deg": hi}
        for (al, a, d, th), (lo, hi) in zip(table_alpha_a_d_theta, limits_deg, strict=True)
    ]
    calibration = None if covariance is None else {"covariance": covariance.tolist()}
    return RobotFile.model_validate({"name": "JR680", "joints": joints, "calibration": calibration})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    world = World.create(0)
    limits = world.nominal.limits_deg
    covariance = np.diag(np.tile([0.01, 0.05, 0.05, 0.01], 6) ** 2)  # deg, mm: a plausible calibration
    nominal = robot_file(world.nominal.table, limits)
    calibrated = robot_file(world.true.table, limits, covariance)
    q_deg = world.random_configurations(args.rows, np.random.default_rng(1))
    folder = Path(tempfile.mkdtemp())
    program_csv = folder / "program.csv"
    header = "step," + ",".join(f"q{i}_deg" for i in range(1, 7))
    rows = np.column_stack([np.arange(args.rows), q_deg])
    np.savetxt(program_csv, rows, fmt=["%d"] + ["%.6f"] * 6, delimiter=",", header=header, comments="")

    nominal_model, calibrated_model = nominal.model(), calibrated.model()
    q = np.radians(q_deg)
    comp = compensate(nominal_model, calibrated_model, q)
    maths = median_time(lambda: compensate(nominal_model, calibrated_model, q), args.repeats)

    def job():
        program = load_program(program_csv)
        return compensation.run(program, calibrated, nominal, table_where="table", nominal_where="robot")

    whole = median_time(job, args.repeats)
    ok = comp.status == Status.OK
    print(f"{args.rows} rows ({ok.sum()} compensated, the rest near singularities or beyond reach)")
    print(f"calib.compensation.compensate, in-process: {maths * 1000:.0f} ms (median of {args.repeats})")
    print(f"whole job in-process (read CSV, compensate, report, write text): {whole * 1000:.0f} ms")


if __name__ == "__main__":
    main()
