"""The mistake checks of ``station.jobs.absorbed`` over simulated seeds: how often they fire on
correct sessions (false alarms), and what they make of the mistakes they are for. Simulated
HSR-JR680 cells (``sim_fixtures.world``), K = 5 readings averaged per capture as ``station sample``
takes them, the setup stating the simulator's noise.

    python benchmarks/mistakes.py [--seeds 20]

Per seed and setting: a clean session, the same with 3 % gross drawstring readings (2-5 mm,
planted; a few per cent must not alarm), line 0's dial_axis flipped, and the dial readings dropped
(with the setup's dial axes, and without them). A false alarm is a warning or refusal of the new
checks on a clean (or 3 % gross) session. For the dial-less runs, the true workspace error (1000
random poses after a rigid fit, as ``station demo`` prints it) against the reported 95 % bound and
the nominal table's.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import configs
from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import Noise, World
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot
from station.jobs import calibration

SETTINGS = ((3, 30), (2, 40), (1, 60))
"""Gauge lines and samples per line."""
NEW = ("dial readings", "down-weighted", "dial reading measures", "nominal table")
"""What the new checks' messages say (a false alarm contains one)."""


def session(seed: int, n_lines: int, per_line: int, outliers: float):
    """A simulated session as the calibration service takes it, its setup and its world."""
    world = dataclasses.replace(World.create(seed, n_lines=n_lines), noise=Noise(q_deg=0.0))
    rng = np.random.default_rng(seed + 1000)
    s = world.sample_set(per_line, rng, outliers, 5)
    setup = SetupFile.model_validate(setup_dict(dataclasses.replace(world, noise=Noise()), rng))
    return Samples(f"seed {seed}", "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line), setup, world


def true_rmse(world: World, x: np.ndarray) -> float:
    """The table's true workspace error [mm]: 1000 random poses, rigid fit (``station demo``'s)."""
    q = world.random_configurations(1000, np.random.default_rng(7))
    p = tcp_position(dh_table(x), np.radians(q), np.zeros(3))
    return float(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))


def alarms(report) -> list[str]:
    messages = [*report.warnings, report.fit_check.refusal or ""]
    return [m for m in messages if any(key in m for key in NEW)]


def flipped(setup: SetupFile) -> SetupFile:
    lines = [
        ln.model_copy(update={"dial_axis": [-v for v in ln.dial_axis]}) if ln.id == 0 else ln
        for ln in setup.lines
    ]
    return setup.model_copy(update={"lines": lines})


def without_axes(setup: SetupFile) -> SetupFile:
    lines = [ln.model_copy(update={"dial_axis": None}) for ln in setup.lines]
    return setup.model_copy(update={"lines": lines, "dial": None})


def run(seeds: int, n_lines: int, per_line: int) -> dict:
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    out = {"clean": 0, "gross": 0, "flip_refused": 0, "dialless": [], "noaxis": []}
    for seed in range(seeds):
        samples, setup, world = session(seed, n_lines, per_line, 0.0)
        out["clean"] += bool(alarms(calibration.calibrate_samples(samples, robot, setup).report))
        gross, setup_g, _ = session(seed, n_lines, per_line, 0.03)
        out["gross"] += bool(alarms(calibration.calibrate_samples(gross, robot, setup_g).report))
        report = calibration.calibrate_samples(samples, robot, flipped(setup)).report
        out["flip_refused"] += "run against its dial_axis" in (report.fit_check.refusal or "")
        unread = dataclasses.replace(samples, dial_mm=np.full(len(samples), np.nan))
        for key, s in (("dialless", setup), ("noaxis", without_axes(setup))):
            o = calibration.calibrate_samples(unread, robot, s)
            ws, check = o.report.workspace, o.report.fit_check
            out[key].append(
                (true_rmse(world, o.calibration.x), ws.predicted_rmse_95_mm, check.nominal_rmse_mm,
                 true_rmse(world, o.calibration.before.x), bool(check.refusal))
            )  # fmt: skip
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    t0 = time.perf_counter()
    print(f"{args.seeds} seeds per setting")
    print(
        "| lines x samples | false alarms, clean | false alarms, 3 % gross | flipped dial_axis refused "
        "| dial-less: true inside 95 % bound, better than nominal (refused) | no dial axes: same |"
    )
    print("|---|---|---|---|---|---|")
    for n_lines, per_line in SETTINGS:
        c = run(args.seeds, n_lines, per_line)
        cells = []
        for key in ("dialless", "noaxis"):
            rows = np.array(c[key], float)
            written = rows[:, 4] == 0
            inside = int(np.sum(written & (rows[:, 0] <= rows[:, 1])))
            better = int(np.sum(written & (rows[:, 0] < rows[:, 3])))
            cells.append(
                f"{inside} / {better} of {int(written.sum())} written ({int((~written).sum())} refused); "
                f"median true {np.median(rows[:, 0]):.3f} mm, bound {np.median(rows[:, 1]):.3f}, "
                f"nominal {np.median(rows[:, 3]):.2f}"
            )
        print(
            f"| {n_lines} x {per_line} | {c['clean']} / {args.seeds} | {c['gross']} / {args.seeds} "
            f"| {c['flip_refused']} / {args.seeds} | {cells[0]} | {cells[1]} |",
            flush=True,
        )
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
