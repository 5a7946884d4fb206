"""A compensated program on the simulated cell, judged against the truth (docs/how-to/compensate.md).

    python benchmarks/compensate_accuracy.py [--table demo-out/corrected.toml] [--seed 0] [--poses 1000]

The program is ``--poses`` random configurations within the joint limits, written with the nominal
HSR-JR680; ``station compensate``'s job rewrites it for the calibrated table, and the true robot of
``World.create(seed)`` (the cell ``station demo`` and ``station sim serve`` simulate with that seed)
runs both. Errors are TCP distances to the meant positions after the best rigid fit of the base.
Without ``--table`` the three-line cell of ``seed`` is sampled (70 poses a line) and calibrated here.
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np

import configs
from calib.kinematics import tcp_position
from calib.metrics import aligned_errors
from sim_fixtures.scenario import write_scenario
from sim_fixtures.world import World
from station.formats.base import toml_text
from station.formats.program import load_program
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs import compensate as compensation
from station.jobs.calibration import calibrate_samples
from station.jobs.report import corrected_table


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def calibrated_table(folder: Path, seed: int) -> Path:
    sc = write_scenario(folder, seed=seed, n_lines=3, n_per_line=70)
    samples, robot = load_samples(sc.samples), load_robot(sc.robot)
    outcome = calibrate_samples(samples, robot, load_setup(sc.setup))
    path = folder / "corrected.toml"
    path.write_text(toml_text(corrected_table(robot, outcome.calibration, samples, "lmlc")))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--table", type=Path, help="corrected table of the simulated cell (default: calibrate one)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--poses", type=int, default=1000)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp())
    table_path = args.table or calibrated_table(folder, args.seed)
    world = World.create(args.seed)
    q = world.random_configurations(args.poses, np.random.default_rng(11))
    program_csv = folder / "program.csv"
    with program_csv.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([f"q{i}_deg" for i in range(1, 7)])
        writer.writerows([[f"{v:.6f}" for v in row] for row in q])
    table, nominal = load_robot(table_path), load_robot(configs.path("robots/hsr_jr680.toml"))
    outcome = compensation.run(
        load_program(program_csv), table, nominal, table_where=str(table_path), nominal_where="hsr_jr680"
    )
    out_csv = folder / "compensated.csv"
    out_csv.write_text(outcome.text)
    rows = list(csv.DictReader(out_csv.open()))
    q_out = np.array([[float(r[f"q{i}_deg"]) for i in range(1, 7)] for r in rows])
    ok = np.array([r["status"] == "ok" for r in rows])
    meant = world.nominal.tcp(q)
    model = table.model()
    print(f"table {table_path}, truth World.create({args.seed}), {args.poses} random poses")
    counts = {k: v for k, v in outcome.report["status_counts"].items() if v}
    print(f"compensated {ok.sum()} rows; statuses: {counts}")
    everything = rms(aligned_errors(meant, world.true_tcp_mm(q)))
    print(f"true TCP error, all rows uncompensated:    {everything:.3f} mm RMS")
    for what, joints in (("uncompensated", q), ("compensated", q_out)):
        err = aligned_errors(meant[ok], world.true_tcp_mm(joints[ok]))
        print(f"true TCP error, compensated rows, {what}: {rms(err):.3f} mm RMS, max {err.max():.3f}")
    table_err = aligned_errors(
        tcp_position(model.dh, np.radians(q[ok]), model.tool), world.true_tcp_mm(q[ok])
    )
    print(f"the table's own error at those poses:      {rms(table_err):.3f} mm RMS")
    if outcome.report["predicted"]:
        p = outcome.report["predicted"]
        print(f"predicted (covariance): {p['rmse_mm']:.3f} mm RMS, 95 %: {p['rmse_95_mm']:.3f}")


if __name__ == "__main__":
    main()
