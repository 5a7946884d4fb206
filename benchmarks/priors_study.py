"""Hold or estimate? A table parameter the data determines no better than its manufacturing tolerance
is held at nominal today, though the real robot has an error there; estimated under its prior
instead, it may move towards the truth. Simulated HSR-JR680 cells, truth known.

    python benchmarks/priors_study.py [--worlds 12] [--noise 1.0]

Per world (seeds 200, 201, ...): one line with 200 samples, three lines with 70 each (the
shipped cell's placements) and one line with 40 (few samples: there the data leaves some
parameters weakly determined), calibrated twice by the station's pipeline, weakly determined
parameters held or estimated under their prior (exact redundancies held either way). For each:
the TRUE workspace error (1,000 random poses within the limits, rigid base re-fit), the predicted
one (``workspace.predicted_rmse_mm``) and their ratio; "change" is the true error's paired
difference against holding. ``--noise`` scales every instrument's noise
(the demo averages readings: about 0.3).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.calibrate import CalibrationOptions, calibrate  # noqa: E402
from calib.kinematics import dh_table, tcp_position  # noqa: E402
from calib.metrics import aligned_errors  # noqa: E402
from sim_fixtures.scenario import setup_dict  # noqa: E402
from sim_fixtures.world import World  # noqa: E402
from station.formats.samples import Samples  # noqa: E402
from station.formats.tables import SetupFile, load_robot  # noqa: E402
from station.jobs.calibration import build_model, predicted_workspace  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = ((1, 200), (3, 70), (1, 40))
VARIANTS = {"hold": True, "estimate": False}


def workspace_rms(world: World, x: np.ndarray) -> float:
    """True RMS TCP error [mm] of table ``x`` over 1,000 random poses, after a rigid base re-fit."""
    q = world.random_configurations(1000, np.random.default_rng(99))
    p = tcp_position(dh_table(x), np.radians(q), world.nominal.tool)
    return float(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))


def cell(seed: int, n_lines: int, per_line: int, noise: float):
    """A world, its measured samples as a station sample set and its setup file."""
    world = World.create(seed, n_lines=n_lines)
    scaled = {
        f.name: getattr(world.noise, f.name) * (noise if f.name != "placement_mm" else 1.0)
        for f in dataclasses.fields(world.noise)
    }
    world = dataclasses.replace(world, noise=dataclasses.replace(world.noise, **scaled))
    rng = np.random.default_rng(seed + 1000)
    s = world.sample_set(per_line, rng)
    samples = Samples(f"world{seed}", "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line)
    return world, samples, SetupFile.model_validate(setup_dict(world, rng))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--worlds", type=int, default=12)
    parser.add_argument("--noise", type=float, default=1.0, help="factor on every instrument's noise")
    args = parser.parse_args()
    robot = load_robot(ROOT / "configs/robots/hsr_jr680.toml")
    t0 = time.perf_counter()
    for n_lines, per_line in SETTINGS:
        rows = {name: [] for name in VARIANTS}
        for seed in range(200, 200 + args.worlds):
            world, samples, setup = cell(seed, n_lines, per_line, args.noise)
            model = build_model(samples, robot, setup, "setup")
            for name, hold in VARIANTS.items():
                cal = calibrate(model, CalibrationOptions(hold_weak=hold))
                true = workspace_rms(world, cal.x)
                predicted = predicted_workspace(robot, cal, model).predicted_rmse_mm
                held = sum(1 for r in cal.held.values() if "no better than" in r)
                rows[name].append((true, predicted, true / predicted, held))
        print(
            f"\n{n_lines} line(s), {n_lines * per_line} samples, {args.worlds} worlds, "
            f"noise x{args.noise:g}: mean +- standard error (ratio: min-max, RMS)"
        )
        print("| weak | held for weakness | true workspace [mm] | change | predicted [mm] | true / pred. |")
        print("|---|---|---|---|---|---|")
        held = np.array(rows["hold"])
        for name, values in rows.items():
            a = np.array(values)
            se = a.std(axis=0, ddof=1) / np.sqrt(len(a))
            change = a[:, 0] - held[:, 0]
            ratio = a[:, 2]
            print(
                f"| {name} | {a[:, 3].mean():.1f} | {a[:, 0].mean():.3f} +- {se[0]:.3f} | "
                f"{change.mean():+.3f} +- {change.std(ddof=1) / np.sqrt(len(a)):.3f} | "
                f"{a[:, 1].mean():.3f} +- {se[1]:.3f} | {ratio.min():.2f}-{ratio.max():.2f}, "
                f"RMS {np.sqrt(np.mean(ratio**2)):.2f} |"
            )
    print(f"\n{time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
