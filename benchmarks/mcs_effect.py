"""Does selecting a subset (MCS-LMLC, M9) help against LMLC on all samples? Simulated HSR-JR680.

    python benchmarks/mcs_effect.py [--seeds 5]

Per seed: 200 samples on one gauge line (the paper's setting) and 3 x 70 on three lines; hold-out
RMSE (60 samples on the same lines) and the TRUE workspace error over 1,000 random poses (rigid
base re-fit), for LMLC on all samples and MCS-LMLC with N = 72 and with N where O1 flattens.
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np

from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from sim_fixtures.scenario import write_scenario
from station.formats.samples import load_samples
from station.formats.tables import load_robot, load_setup
from station.jobs import calibration


def workspace_rms(world, x) -> float:
    q = world.random_configurations(1000, np.random.default_rng(99))
    p = tcp_position(dh_table(x), np.radians(q), np.zeros(3))
    return float(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    variants = {
        "lmlc (all)": ("lmlc", None),
        "mcs-lmlc N=72": ("mcs-lmlc", 72),
        "mcs-lmlc N=auto": ("mcs-lmlc", None),
    }
    for n_lines, per_line in ((1, 200), (3, 70)):
        results = {name: [] for name in variants}
        for seed in range(args.seeds):
            sc = write_scenario(tempfile.mkdtemp(), seed=100 + seed, n_lines=n_lines, n_per_line=per_line)
            files = load_samples(sc.samples), load_robot(sc.robot), load_setup(sc.setup)
            for name, (method, n) in variants.items():
                out = calibration.calibrate_samples(
                    *files, holdout=load_samples(sc.holdout), method=method, select=n
                )
                results[name].append(
                    (out.report.after.holdout.rmse_mm, workspace_rms(sc.world, out.calibration.x))
                )
        print(
            f"\n{n_lines} line(s), {n_lines * per_line} samples, {args.seeds} seeds: mean +- standard error"
        )
        print("| method | hold-out RMSE [mm] | true workspace RMSE [mm] |\n|---|---|---|")
        for name, rows in results.items():
            a = np.array(rows)
            se = a.std(axis=0, ddof=1) / np.sqrt(len(a))
            print(f"| {name} | {a[:, 0].mean():.4f} +- {se[0]:.4f} | {a[:, 1].mean():.3f} +- {se[1]:.3f} |")


if __name__ == "__main__":
    main()
