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
from station.history import moves  # noqa: E402
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
    p.add_argument(
        "--history",
        action="store_true",
        help="also: two more calibrations per cell (again, then after the change) and what the "
        "history flags between consecutive ones",
    )
    args = p.parse_args(argv)
    nominal = load_robot(configs.path("robots/hsr_jr680.toml"))
    sim_setup = load_setup(configs.path("setups/sim.toml"))
    plans = {n: verify_design(nominal, sim_setup, n_select=n).plan for n in args.poses}
    counts = {n: {"false": 0, "caught": 0, "named": 0} for n in args.poses}
    flags = {"J2.a_mm flagged": 0, "cells with another flag": 0, "other flags": 0}
    t0 = time.perf_counter()
    for seed in range(args.seeds):
        world = World.create(seed)
        rng = np.random.default_rng([seed, 1])
        setup = SetupFile.model_validate(setup_dict(world, rng))
        train = as_samples(world.sample_set(args.train, rng, readings=5), "train")
        outcome = calibrate_samples(train, nominal, setup, terms="geometric")
        table = RobotFile.model_validate(corrected_table(nominal, outcome.calibration, train, "lmlc"))
        if args.history:
            flagged = history_flags(world, nominal, setup, rng, args.train, report_of(outcome))
            flags["J2.a_mm flagged"] += any(m["param"] == "J2.a_mm" and m["record"] == 3 for m in flagged)
            others = [m for m in flagged if not (m["param"] == "J2.a_mm" and m["record"] == 3)]
            flags["cells with another flag"] += bool(others)
            flags["other flags"] += len(others)
            for m in others:
                print(
                    f"  cell {seed}: also flagged {m['param']} {m['change']:+.3g} "
                    f"({m['sigmas']:.1f} sigma) at record {m['record']}"
                )
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
    if args.history:
        print(f"history of 3 calibrations (the third after the change): {flags} of {args.seeds} cells")
    return 0


def report_of(outcome) -> dict:
    return outcome.report.as_json()


def history_flags(world, nominal, setup, rng, per_line: int, first: dict) -> list[dict]:
    """``station.history.moves`` over three calibrations: ``first``, the cell again, the cell
    after ``CHANGE`` (records 1, 2, 3)."""
    reports = [first]
    for w in (world, world.changed(CHANGE)):
        train = as_samples(w.sample_set(per_line, rng, readings=5), "train")
        reports.append(report_of(calibrate_samples(train, nominal, setup, terms="geometric")))
    records = [
        {"id": k + 1, "command": "calibrate", "time_utc": f"record {k + 1}", "figures": r}
        for k, r in enumerate(reports)
    ]
    return moves(records)


if __name__ == "__main__":
    sys.exit(main())
