"""Down-weighted rows on clean simulated sessions: how often the robust loss calls a good reading
gross, with its scale floored at the stated noise (the product) and from the residuals' MAD alone
(before issue 16). Simulated HSR-JR680 cells, the setup stating the simulator's noise.

    python benchmarks/false_alarms.py [--seeds 10]

Two kinds of capture: ``stated`` (one reading per capture at the stated noise, joint readings
0.0005 deg) and ``averaged`` (as ``station sample`` captures on the simulated devices: K = 5
drawstring and dial readings averaged, each quantised to 1 um, the joints exact). Per setting and
seed one clean session (every row good) and the same session with 3 % gross drawstring readings
(2-5 mm, planted): false alarms are down-weighted clean rows, "found" the planted rows down-weighted.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import calib.calibrate
import configs
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import Noise, World
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot
from station.jobs import calibration

CAPTURES = {"stated": (Noise(), 1), "averaged": (Noise(q_deg=0.0), 5)}
"""Kind of capture: the simulator's instruments and the readings averaged per capture."""
SETTINGS = ((1, 60), (3, 30), (3, 70))
"""Gauge lines and samples per line."""
OUTLIER_FRACTION = 0.03


def mad_alone(scale: np.ndarray, options) -> np.ndarray:
    """The loss scale before issue 16: ``loss_threshold`` MAD scales, however small."""
    return options.loss_threshold * scale


def session(seed: int, n_lines: int, per_line: int, capture: str, outliers: bool):
    """A clean (or 3 % gross) simulated session as the calibration service takes it."""
    noise, readings = CAPTURES[capture]
    world = dataclasses.replace(World.create(seed, n_lines=n_lines), noise=noise)
    rng = np.random.default_rng(seed + 1000)
    s = world.sample_set(per_line, rng, OUTLIER_FRACTION if outliers else 0.0, readings)
    setup = SetupFile.model_validate(setup_dict(dataclasses.replace(world, noise=Noise()), rng))
    samples = Samples(f"seed {seed}", "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line)
    return samples, setup, set(s.outliers.tolist())


def counts(seeds: int, n_lines: int, per_line: int, capture: str) -> dict[str, int]:
    """Down-weighted clean rows (both scales) and planted rows found, summed over ``seeds``."""
    robot = load_robot(configs.path("robots/hsr_jr680.toml"))
    out = dict.fromkeys(("rows", "floored", "mad", "planted", "found", "false_with_planted"), 0)
    floored = calib.calibrate.loss_scale
    for seed in range(seeds):
        samples, setup, _ = session(seed, n_lines, per_line, capture, outliers=False)
        out["rows"] += len(samples)
        for key, scale in (("floored", floored), ("mad", mad_alone)):
            calib.calibrate.loss_scale = scale
            try:
                report = calibration.calibrate_samples(samples, robot, setup).report
            finally:
                calib.calibrate.loss_scale = floored
            out[key] += len(report.downweighted)
        samples, setup, planted = session(seed, n_lines, per_line, capture, outliers=True)
        flagged = set(calibration.calibrate_samples(samples, robot, setup).report.downweighted)
        out["planted"] += len(planted)
        out["found"] += len(planted & flagged)
        out["false_with_planted"] += len(flagged - planted)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    t0 = time.perf_counter()
    print(f"{args.seeds} seeds per setting; down-weighted clean rows (of all clean rows), planted found")
    print(
        "| capture | lines x samples | clean rows | false alarms, floored scale | false alarms, MAD alone "
        "| planted found (floored) | false alarms beside them |"
    )
    print("|---|---|---|---|---|---|---|")
    for capture in CAPTURES:
        for n_lines, per_line in SETTINGS:
            c = counts(args.seeds, n_lines, per_line, capture)
            print(
                f"| {capture} | {n_lines} x {per_line} | {c['rows']} | {c['floored']} | {c['mad']} "
                f"| {c['found']} / {c['planted']} | {c['false_with_planted']} |",
                flush=True,
            )
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
