"""``station verify`` over many simulated cells: how often an unchanged cell is called "drifted"
(false alarms; target under 1 in 20) and how often a cell whose J2 link grew by 0.3 mm is caught,
with J2.a_mm among the named parameters.

Per seed: a JR680 cell (``World.create(seed)``), calibrated on 3 lines x ``--train`` poses (5
readings per capture) through the calibration service, the table written as ``station calibrate``
writes it; then ``station plan --verify N``'s plan measured on the cell as it is and after the
change, each verified. Usage: ``python benchmarks/verify_drift.py [--seeds 40] [--poses 15 30 60]``.

Measured (40 seeds, 3 x 70 training poses, 175 s on the shared 2-core machine): unchanged cell
called drifted 0/40 for each of 15, 30, 60 poses; J2.a +0.3 mm caught and named 23/40, 33/40, 40/40.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import configs  # noqa: E402
from sim_fixtures.scenario import setup_dict  # noqa: E402
from sim_fixtures.world import World  # noqa: E402
from station.formats.samples import Samples  # noqa: E402
from station.formats.tables import RobotFile, SetupFile, load_robot, load_setup  # noqa: E402
from station.jobs.calibration import calibrate_samples  # noqa: E402
from station.jobs.planning import verify_design  # noqa: E402
from station.jobs.report import corrected_table  # noqa: E402
from station.jobs.verification import verify_samples  # noqa: E402

CHANGE = {"J2.a_mm": 0.3}


def as_samples(s, name: str) -> Samples:
    return Samples(name, "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=40)
    p.add_argument(
        "--train", type=int, default=70, help="training poses per line (default 70, as sim serve's plan)"
    )
    p.add_argument("--poses", type=int, nargs="+", default=[15, 30], help="verification plan sizes")
    args = p.parse_args(argv)
    nominal = load_robot(configs.path("robots/hsr_jr680.toml"))
    sim_setup = load_setup(configs.path("setups/sim.toml"))
    plans = {n: verify_design(nominal, sim_setup, n_select=n).plan for n in args.poses}
    counts = {n: {"false": 0, "caught": 0, "named": 0} for n in args.poses}
    t0 = time.perf_counter()
    for seed in range(args.seeds):
        world = World.create(seed)
        rng = np.random.default_rng([seed, 1])
        setup = SetupFile.model_validate(setup_dict(world, rng))
        train = as_samples(world.sample_set(args.train, rng, readings=5), "train")
        outcome = calibrate_samples(train, nominal, setup, terms="geometric")
        table = RobotFile.model_validate(corrected_table(nominal, outcome.calibration, train, "lmlc"))
        for n, plan in plans.items():
            for name, w in (("fresh", world), ("changed", world.changed(CHANGE))):
                q, lines = w.touch_lines(plan.q_deg, plan.line, rng)
                report = verify_samples(
                    as_samples(w.measure(q, lines, rng, readings=5), name), table, setup
                ).report
                drifted = report.verdict == "drifted"
                if name == "fresh":
                    counts[n]["false"] += drifted
                else:
                    counts[n]["caught"] += drifted
                    counts[n]["named"] += drifted and "J2.a_mm" in [x.param for x in report.likely]
    print(
        f"{args.seeds} simulated cells, calibrated on 3 lines x {args.train} poses "
        f"({time.perf_counter() - t0:.0f} s)"
    )
    for n, c in counts.items():
        print(
            f"verification plan of {n} poses: unchanged cell called drifted {c['false']}/{args.seeds}; "
            f"J2.a +0.3 mm caught {c['caught']}/{args.seeds}, J2.a_mm named {c['named']}/{args.seeds}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
