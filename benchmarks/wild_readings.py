"""One wild drawstring reading within the loader's ranges, planted in small simulated sessions: the
true workspace error of the calibrated table with and without it, and what ``station calibrate``
says (down-weighted, warned, refused). Simulated HSR-JR680 cells (``sim_fixtures.world``), one
reading per capture at the stated noise.

    python benchmarks/wild_readings.py [--seeds 8] [--per-line 12] [--off 5 50 1000]

Per seed: 3 gauge lines x ``--per-line`` poses, row 7's cable reading moved by each ``--off`` [mm].
Before the table fit's first round was robust (least squares, then the robust rounds from there),
seed 2's 36 rows with one reading 1000 mm off gave a table 1625 mm wrong over the workspace.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import configs  # noqa: E402
from benchmarks.mistakes import true_rmse  # noqa: E402
from sim_fixtures.scenario import setup_dict  # noqa: E402
from sim_fixtures.world import World  # noqa: E402
from station.formats.samples import Samples  # noqa: E402
from station.formats.tables import SetupFile, load_robot  # noqa: E402
from station.jobs.calibration import calibrate_samples  # noqa: E402

ROW = 7


def outcome_text(world: World, samples: Samples, robot, setup) -> str:
    """The true workspace error [mm] of the calibrated table and whether row ``ROW`` was left out."""
    out = calibrate_samples(samples, robot, setup, terms="geometric")
    check = out.report.fit_check
    said = "refused" if check.refusal else ("left out" if ROW in out.report.downweighted else "kept")
    return f"{true_rmse(world, out.calibration.x):.3f} mm, {said}"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--per-line", type=int, default=12)
    p.add_argument("--off", type=float, nargs="+", default=[5.0, 50.0, 1000.0])
    args = p.parse_args(argv)
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    t0 = time.perf_counter()
    print("| seed | clean | " + " | ".join(f"row {ROW} {off:+g} mm" for off in args.off) + " |")
    print("|---|---|" + "---|" * len(args.off))
    for seed in range(args.seeds):
        world = World.create(seed)
        rng = np.random.default_rng([seed, 1])
        setup = SetupFile.model_validate(setup_dict(world, rng))
        s = world.sample_set(args.per_line, rng, readings=1)
        cells = []
        for off in [0.0, *args.off]:
            length = s.length_mm.copy()
            length[ROW] += off
            rows = Samples(f"seed {seed}", "drawstring", s.q_deg, length, s.dial_mm, s.line)
            cells.append(outcome_text(world, rows, robot, setup))
        print(f"| {seed} | " + " | ".join(cells) + " |", flush=True)
    print(f"({time.perf_counter() - t0:.0f} s; true workspace error, 1000 random poses after a rigid fit)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
