"""Sweep plans compared offline (issue 37): a plan's true workspace error over seeds in a minute.

    python benchmarks/sweep_plan_study.py [--passes 2] [--extra 2] [--tilt 25] [--roll 60]
        [--seeds 0 1 2 3] [--draws 1] [--late-ms 0] [--untimed] [--static | --compare]
        [--noise-free | --noise-of drawstring|dial] [--row-hz 240]

``station plan --sweep`` on the demo's robot and setup (``--passes`` a line, ``--extra`` more,
``--tilt`` / ``--roll`` the largest tool turns [deg], default the demo's
``calib.sweep.PassShape``); then per seed the demo's simulated cell
sweeps it as ``station demo --sweep`` does (``sim_fixtures.station_sim.sweep_cell``, the
``SweepRobot`` with the demo's speeds and dwells), rows at the plan's rate along every sweep, each
read once at the simulator's instrument noise with the joints exact (its controller's are), every
row kept; LMLC as ``station calibrate`` runs it; the true workspace error on 1,000 random poses.
What ``benchmarks/demo_sweep.py`` measures, less the stream's timing and flags: a plan's limit.
``--late-ms D``: the drawstring's lengths true ``D`` ms after the rows' stamps (a device measuring
earlier in its round trip than the station assumes); ``--untimed``: the rows without their
``pass`` and ``t_s`` columns, so the calibration fits no timing (``calib.drawstring.TIMING_NAME``).
``--noise-free``: the drawstring and the dial read without noise (their 1 um resolution kept):
what the plan's rows cannot tell of the table, whatever its noise: its floor (a direction the rows
barely determine: on seed 0 the same with the prior weakened a hundredfold or removed, and the
true table fits the rows no better than the fitted one). ``--noise-of``: only that instrument's
noise (which of the two a plan's error comes from).
``--row-hz``: rows a second along the sweeps (the planner's and the rows'; default the station's).
``--static``: the static demo's plan instead (``station plan``, each pose read 5 times and
averaged), through the same pipeline: the comparison over draws that one demo run cannot give.
``--compare``: both, the static plan first, and per seed how many pairs of their draws find the
sweep no worse (a seed's one demo run of each is one such pair).
``--draws K``: the rows read K times with fresh noise (the first draw is the one-draw run's), each
calibrated; their true errors, mean and range (one seed's error moves by a factor 2-3 between
draws of the noise alone, so a single draw compares plans poorly).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import configs  # noqa: E402
from calib.methods import DEFAULT_TERM_MODEL  # noqa: E402
from calib.sweep import PassShape  # noqa: E402
from sim_fixtures.station_sim import planned_cell, sweep_cell, sweep_robot  # noqa: E402
from sim_fixtures.sweep_program import swept_rows, write_swept  # noqa: E402
from sim_fixtures.world import Noise  # noqa: E402
from station.commands.demo import HOLDOUT_PER_LINE, demo_config, truth_line  # noqa: E402
from station.config import StationConfig  # noqa: E402
from station.formats.samples import load_samples  # noqa: E402
from station.formats.tables import load_robot, load_setup  # noqa: E402
from station.jobs import calibration, planning, sweeping  # noqa: E402

READINGS = 5
"""Readings a static pose averages (the demo's ``[session] readings``)."""


def read_noise(args) -> Noise:
    """The simulator's instrument noise, the joints exact; none at all with ``--noise-free``, one
    instrument's alone with ``--noise-of``."""
    if args.noise_free:
        return Noise(length_mm=0.0, dial_mm=0.0, q_deg=0.0)
    quiet = {"drawstring": {"dial_mm": 0.0}, "dial": {"length_mm": 0.0}}.get(args.noise_of, {})
    return Noise(q_deg=0.0, **quiet)


def sweep_reads(args, robot_file, setup, setup_path):
    """The sweep plan's ``(promise line, per seed: world, rows written per draw, rows, robot time)``."""
    shape = PassShape(max_tilt_deg=args.tilt, max_roll_deg=args.roll)
    limits = dataclasses.replace(sweeping.SWEEP, row_hz=args.row_hz)
    design = sweeping.sweep_design(
        robot_file, setup, str(setup_path), passes=args.passes, extra=args.extra, shape=shape, sweep=limits
    )
    plan, config = design.plan, StationConfig.model_validate(demo_config(0, sweep=True))
    promise = design.report["predicted"]["plan"]["predicted_rmse_mm"]

    def cells(seed):
        cell, paths = sweep_cell(seed, plan.q_deg, plan.line, plan.sweep_pass)
        robot = sweep_robot(config, paths)
        rows = swept_rows(robot, cell.plan_lines, paths, args.row_hz, args.late_ms / 1e3)
        world = dataclasses.replace(cell.world, noise=read_noise(args))
        write = functools.partial(write_swept, world, rows, timed=not args.untimed)
        return world, write, len(rows.q), f"{robot.cycle_s:.1f}"

    return f"{len(design.report['passes'])} passes, promising {promise:.3f} mm", cells


def static_reads(args, robot_file, setup, setup_path):
    """The static demo's plan (``station plan`` as the demo runs it), each pose read ``READINGS``
    times and averaged, as :func:`sweep_reads`."""
    design = planning.design(
        robot_file, setup, str(setup_path), n_select=None, suggest=False, readings=READINGS
    )
    plan, promise = design.plan, design.report["predicted"]["plan"]["predicted_rmse_mm"]

    def cells(seed):
        cell = planned_cell(seed, plan.q_deg, plan.line)
        world = dataclasses.replace(cell.world, noise=read_noise(args))

        def write(rng, path):
            world.measure(cell.plan_deg, cell.plan_lines, rng, readings=READINGS).to_csv(path)

        return world, write, len(cell.plan_deg), "-"

    return f"{len(plan)} static poses, promising {promise:.3f} mm", cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--passes", type=int, default=2)
    parser.add_argument("--extra", type=int, default=2)
    parser.add_argument("--tilt", type=float, default=PassShape.max_tilt_deg)
    parser.add_argument("--roll", type=float, default=PassShape.max_roll_deg)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--draws", type=int, default=1)
    parser.add_argument("--late-ms", type=float, default=0.0)
    parser.add_argument("--untimed", action="store_true")
    plans = parser.add_mutually_exclusive_group()
    plans.add_argument("--static", action="store_true")
    plans.add_argument("--compare", action="store_true")
    noise = parser.add_mutually_exclusive_group()
    noise.add_argument("--noise-free", action="store_true")
    noise.add_argument("--noise-of", choices=["drawstring", "dial"])
    parser.add_argument("--row-hz", type=float, default=sweeping.SWEEP.row_hz)
    args = parser.parse_args()
    robot_file, setup_path = (
        load_robot(configs.path("robots/hsr_jr680.toml")),
        configs.path("setups/sim.toml"),
    )
    setup = load_setup(setup_path)
    kinds = [static_reads, sweep_reads] if args.compare else [static_reads if args.static else sweep_reads]
    folder = Path(tempfile.mkdtemp(prefix="sweep-plan-study-"))
    trues = {}
    for reads in kinds:
        said, cells = reads(args, robot_file, setup, setup_path)
        print(said)
        print("seed | robot time [s] | rows | true error [mm]")
        trues[reads] = {
            seed: true_errors(args, cells, seed, robot_file, setup, setup_path, folder) for seed in args.seeds
        }
    if args.compare:
        print("seed | pairs of draws where the sweep is no worse than the static plan")
        for seed in args.seeds:
            static, swept = np.array(trues[static_reads][seed]), np.array(trues[sweep_reads][seed])
            print(f"{seed} | {np.sum(swept[:, None] <= static[None, :])} of {static.size * swept.size}")


def true_errors(args, cells, seed, robot_file, setup, setup_path, folder) -> list[float]:
    """One seed's true workspace errors [mm], a calibration per draw of the noise, printed as a row."""
    world, write, n_rows, robot_time = cells(seed)
    world.sample_set(HOLDOUT_PER_LINE, np.random.default_rng([seed, 4])).to_csv(folder / "holdout.csv")
    trues = []
    for draw in range(args.draws):
        write(np.random.default_rng([seed, 1] + ([draw] if draw else [])), folder / "rows.csv")
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
    listed = " / ".join(f"{v:.3f}" for v in trues)
    print(f"{seed} | {robot_time} | {n_rows} | {listed}{spread}", flush=True)
    return trues


if __name__ == "__main__":
    main()
