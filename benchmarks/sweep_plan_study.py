"""Sweep plans compared offline (issue 37): a plan's true workspace error over seeds in a minute.

    python benchmarks/sweep_plan_study.py [--passes 2] [--extra 2] [--tilt 25] [--roll 60]
        [--seeds 0 1 2 3] [--draws 1]

``station plan --sweep`` on the demo's robot and setup (``--passes`` a line, ``--extra`` more,
``--tilt`` / ``--roll`` the largest tool turns [deg]); then per seed the demo's simulated cell
sweeps it as ``station demo --sweep`` does (``sim_fixtures.station_sim.sweep_cell``, the
``SweepRobot`` with the demo's speeds and dwells), rows at the plan's rate along every sweep, each
read once at the simulator's instrument noise with the joints exact (its controller's are), every
row kept; LMLC as ``station calibrate`` runs it; the true workspace error on 1,000 random poses.
What ``benchmarks/demo_sweep.py`` measures, less the stream's timing and flags: a plan's limit.
``--draws K``: the rows read K times with fresh noise (the first draw is the one-draw run's), each
calibrated; their true errors, mean and range (one seed's error moves by a factor 2-3 between
draws of the noise alone, so a single draw compares plans poorly).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import configs  # noqa: E402
from calib.methods import DEFAULT_TERM_MODEL  # noqa: E402
from calib.sweep import PassShape  # noqa: E402
from sim_fixtures.station_sim import sweep_cell, sweep_robot  # noqa: E402
from sim_fixtures.sweep_program import SweepRobot  # noqa: E402
from sim_fixtures.world import Noise  # noqa: E402
from station.commands.demo import HOLDOUT_PER_LINE, demo_config, truth_line  # noqa: E402
from station.config import StationConfig  # noqa: E402
from station.formats.samples import load_samples  # noqa: E402
from station.formats.tables import load_robot, load_setup  # noqa: E402
from station.jobs import calibration, sweeping  # noqa: E402


def swept_rows(robot: SweepRobot, plan_lines: np.ndarray, paths: list, hz: float):
    """Joints [deg] (N, 6) and line ids (N,) of the rows ``hz`` a second along every sweep."""
    q, lines = [], []
    for piece in (p for p in robot._pieces if p.kind == "sweep"):
        t = np.arange(piece.start_s, piece.start_s + piece.duration_s, 1.0 / hz)
        q.append(np.array([robot.state(s).q_deg for s in t]))
        lines.append(np.full(len(t), plan_lines[paths[piece.p].rows[0]]))
    return np.concatenate(q), np.concatenate(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--passes", type=int, default=2)
    parser.add_argument("--extra", type=int, default=2)
    parser.add_argument("--tilt", type=float, default=25.0)
    parser.add_argument("--roll", type=float, default=60.0)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--draws", type=int, default=1)
    args = parser.parse_args()
    robot_file, setup_path = (
        load_robot(configs.path("robots/hsr_jr680.toml")),
        configs.path("setups/sim.toml"),
    )
    setup = load_setup(setup_path)
    shape = PassShape(max_tilt_deg=args.tilt, max_roll_deg=args.roll)
    design = sweeping.sweep_design(
        robot_file, setup, str(setup_path), passes=args.passes, extra=args.extra, shape=shape
    )
    plan, config = design.plan, StationConfig.model_validate(demo_config(0, sweep=True))
    promise = design.report["predicted"]["plan"]["predicted_rmse_mm"]
    print(f"{len(design.report['passes'])} passes, promising {promise:.3f} mm")
    print("seed | robot time [s] | rows | true error [mm]")
    folder = Path(tempfile.mkdtemp(prefix="sweep-plan-study-"))
    for seed in args.seeds:
        cell, paths = sweep_cell(seed, plan.q_deg, plan.line, plan.sweep_pass)
        robot = sweep_robot(config, paths)
        q, lines = swept_rows(robot, cell.plan_lines, paths, sweeping.SWEEP.row_hz)
        world = dataclasses.replace(cell.world, noise=Noise(q_deg=0.0))
        world.sample_set(HOLDOUT_PER_LINE, np.random.default_rng([seed, 4])).to_csv(folder / "holdout.csv")
        trues = []
        for draw in range(args.draws):
            rng = np.random.default_rng([seed, 1] + ([draw] if draw else []))
            world.measure(q, lines, rng).to_csv(folder / "rows.csv")
            outcome = calibration.calibrate_samples(
                load_samples(folder / "rows.csv"),
                robot_file,
                setup,
                setup_where=str(setup_path),
                holdout=load_samples(folder / "holdout.csv"),
                method="lmlc",
                terms=DEFAULT_TERM_MODEL,
            )
            trues.append(float(truth_line(world, outcome).split("->")[1].split()[0]))
        spread = f" (mean {np.mean(trues):.3f}, {min(trues):.3f}-{max(trues):.3f})" if args.draws > 1 else ""
        said = " / ".join(f"{v:.3f}" for v in trues)
        print(f"{seed} | {robot.cycle_s:.1f} | {len(q)} | {said}{spread}", flush=True)


if __name__ == "__main__":
    main()
