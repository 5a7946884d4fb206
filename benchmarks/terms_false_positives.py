"""False positives of ``--model auto``: joint-space terms kept on simulated cells that carry none.

    python benchmarks/terms_false_positives.py [--seeds 20]

Every session is calibrated by ``station calibrate``'s service with its default model (``auto``);
the simulated worlds have geometric errors only, so every term kept is a false positive. Settings:

- ``jr680 drawstring``: the simulated JR680 cell (the demo's), gauge lines x samples per line; the
  robot file gives no masses, so only harmonics are candidates;
- ``jr680 + masses``: the same cells with assumed link masses (those of the unit tests), so the
  compliances of the load-bearing joints enter as the prior group too;
- ``ur10 tracker``: a UR10 with machining errors (0.15 deg, 0.75 mm) at random poses seen by a
  laser tracker (0.02 mm per axis), the robot file's masses.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import configs
from calib.kinematics import tcp_position
from calib.params import dh_from_degrees
from calib.position import rotation_from_vector
from sim_fixtures.scenario import setup_dict
from sim_fixtures.world import World
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot
from station.jobs.calibration import calibrate_samples

JR680_MASSES = (
    [40.0, 25.0, 20.0, 8.0, 4.0, 2.0],
    [[-100, 0, 50], [-300, 0, 0], [-50, 0, 0], [0, 0, -250], [0, 0, 0], [0, 0, 30]],
)
"""Assumed JR680 link masses [kg] and centres [mm] (the paper gives none), as in the unit tests."""
SETTINGS = (
    ("jr680 drawstring", 3, 50),
    ("jr680 drawstring", 1, 100),
    ("jr680 + masses", 3, 50),
    ("ur10 tracker", 1, 150),
)
"""Setting, gauge lines (tracker: one placement), samples per line."""


def drawstring_session(seed: int, n_lines: int, per_line: int):
    world = World.create(seed, n_lines=n_lines)
    rng = np.random.default_rng(seed + 1000)
    s = world.sample_set(per_line, rng)
    setup = SetupFile.model_validate(setup_dict(world, rng))
    return Samples(f"seed {seed}", "drawstring", s.q_deg, s.length_mm, s.dial_mm, s.line), setup


def tracker_session(seed: int, n: int, robot):
    rng = np.random.default_rng(seed)
    nominal = dh_from_degrees(robot.table_deg())
    true = nominal + np.column_stack(
        [np.radians(rng.normal(0, 0.15, 6)), rng.normal(0, 0.75, (6, 2)), np.radians(rng.normal(0, 0.15, 6))]
    )
    q = rng.uniform(-180, 180, (n, 6))
    p = tcp_position(true, np.radians(q), np.array(robot.tool_mm))
    p = p @ rotation_from_vector(np.array([0.1, -0.2, 2.5])).T + [2500.0, -1000.0, 200.0]
    p += rng.normal(0, 0.02, p.shape)
    return Samples(f"seed {seed}", "position", q, p, np.full(n, np.nan), np.full(n, -1)), None


def with_masses(robot):
    mass, com = JR680_MASSES
    joints = [
        j.model_copy(update={"mass_kg": m, "com_mm": c})
        for j, m, c in zip(robot.joints, mass, com, strict=True)
    ]
    return robot.model_copy(update={"joints": joints})


def session_terms(setting: str, n_lines: int, per_line: int, seed: int) -> tuple[list[str], str]:
    """The joint-space terms ``--model auto`` keeps on one simulated session of ``setting`` (every
    one a false positive) and the cross-validation's fold scheme."""
    if setting == "ur10 tracker":
        robot = load_robot(configs.path("robots/ur10.toml"))
        samples, setup = tracker_session(seed, per_line, robot)
    else:
        samples, setup = drawstring_session(seed, n_lines, per_line)
        robot = load_robot(configs.path("robots/hsr_jr680.toml"))
        robot = with_masses(robot) if setting == "jr680 + masses" else robot
    report = calibrate_samples(samples, robot, setup, terms="auto").report
    scheme = report.cross_validation.scheme if report.cross_validation else "too few rows"
    return list(report.terms), scheme


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    print(f"{args.seeds} seeds per setting, --model auto on cells without joint-space terms")
    print("| cell | lines x samples | folds | sessions with a term kept | terms kept | s per session |")
    print("|---|---|---|---|---|---|")
    for setting, n_lines, per_line in SETTINGS:
        kept, names, scheme, t0 = 0, [], "", time.perf_counter()
        for seed in range(args.seeds):
            terms, scheme = session_terms(setting, n_lines, per_line, seed)
            kept += bool(terms)
            names += terms
        per = (time.perf_counter() - t0) / args.seeds
        shown = ", ".join(sorted(set(names))) or "none"
        print(
            f"| {setting} | {n_lines} x {per_line} | {scheme} | {kept} / {args.seeds} | {shown} "
            f"| {per:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
