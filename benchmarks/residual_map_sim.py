"""The residual map against the simulated truth (issue 36's done-when figures).

Simulated JR680 cells (``sim_fixtures.world``, ``[sim] unmodelled = "ur10-like"``: joints 2 and 3
off by 0.014 deg 17 times a turn, a sag of 0.15 mm at a metre's reach), each measured on one plan
made with ``station plan --near`` a user's program (``station.jobs.near_planning.near_design``), the
sessions measured as ``station sample`` would (5 readings averaged per capture), calibrated as
``station calibrate`` does (``calibrate_samples``); the map fitted on the calibration's rows:

- ``drawstring``: the calibration's own rows (drawstring along the cable, dial across the lines:
  ``calib.map_rows``), the map as ``station calibrate`` fits it: the joint angle errors beside the
  table they bend, then the shared error (``calib.absorbed_angles.fit_model_map``);
- ``tracker``: a laser tracker's rows at the same poses (noise 0.02 mm per axis), the table's
  frame registered onto the truth on those poses (``calib.residual_map.fit_map``): the map with
  the whole error the calibrated table leaves seen;
- ``ideal``: the same tracker rows of the true table's residual, the unmodelled error alone (no
  calibration absorbing part of it): what the plan and the map reach where the table is right.

At the program's poses near the measured poses (a plan pose within ``calib.near.NEAR_DEG``), the
true TCP against the table's prediction alone and the table's plus the map's (each prediction's
frame registered onto the truth on the measured poses): RMS [mm], how many lie inside the map's 95 % bound
(chi-square, 3 degrees), against the instruments' noise (the drawstring's 0.02 mm). Cells without
the unmodelled error: how many seeds keep the map off. ``--error cyclic`` or ``sag`` gives the cells
one part of the error alone (what each leaves of the figure).

Usage: ``python benchmarks/residual_map_sim.py [--seeds 20] [--near-poses 60]
[--error ur10-like|cyclic|sag] [--rows drawstring|tracker|ideal|all] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from pathlib import Path

for _key in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_key, "1")  # as ``station`` sets them (``station.cli.BLAS_THREADS``)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import configs  # noqa: E402
from calib.absorbed_angles import fit_model_map  # noqa: E402
from calib.kinematics import dh_table, tcp_position  # noqa: E402
from calib.metrics import rigid_fit  # noqa: E402
from calib.near import covered  # noqa: E402
from calib.residual_map import fit_map  # noqa: E402
from sim_fixtures.unmodelled import UR10_LIKE, Unmodelled  # noqa: E402
from sim_fixtures.world import World  # noqa: E402
from station.formats.samples import load_samples  # noqa: E402
from station.formats.tables import load_robot, load_setup  # noqa: E402
from station.jobs.calibration import calibrate_samples  # noqa: E402
from station.jobs.near_planning import near_design  # noqa: E402

CHI2_3_95 = 7.8147
"""95 % quantile of the chi-square distribution with 3 degrees of freedom."""
READINGS = 5
"""Readings averaged per capture (``[session] readings``)."""
PROGRAM_POSES = 60
"""The user's program: poses a few degrees off contacts with the cell's lines."""
TRACKER_MM = 0.02
"""The simulated tracker's noise per axis [mm] (``sim_fixtures.unmodelled.TrackerCell``)."""
ERRORS = {
    "ur10-like": UR10_LIKE,
    "cyclic": dataclasses.replace(UR10_LIKE, sag_mm_per_m2=0.0),
    "sag": dataclasses.replace(UR10_LIKE, cyclic=()),
}
"""The unmodelled errors a cell may carry (``--error``): ``UR10_LIKE`` whole, its cyclic errors
alone, its sag alone."""
ROBOT, SETUP = configs.path("robots/hsr_jr680.toml"), configs.path("setups/sim.toml")


def program_deg(n: int = PROGRAM_POSES, seed: int = 0) -> np.ndarray:
    """A user's program (n, 6) [deg]: contacts of the sim cell's lines moved 3 deg (joints 1-3)
    and 10 deg (the wrist) at most, uniformly: where the robot works, near the gauge lines."""
    rng = np.random.default_rng([seed, 36])
    q, _ = World.create(seed).line_configurations(-(-n // 3), rng)
    q = q[:n]
    return q + np.hstack([rng.uniform(-3, 3, (len(q), 3)), rng.uniform(-10, 10, (len(q), 3))])


def near_plan(program: np.ndarray, near_poses: int):
    """``station plan --near``'s plan for ``program`` on the sim cell's setup."""
    robot, setup = load_robot(ROBOT), load_setup(SETUP)
    return near_design(
        robot, setup, program, str(SETUP), n_near=near_poses, suggest=False, readings=READINGS
    ).plan


def session(world: World, plan, seed: int):
    """The plan measured on ``world`` (touched, READINGS averaged), calibrated; the samples, the
    true configurations and the outcome."""
    rng = np.random.default_rng([seed, 9])
    q_true, lines = world.touch_lines(plan.q_deg, plan.line, rng)
    measured = world.measure(q_true, lines, rng, readings=READINGS)
    with tempfile.TemporaryDirectory() as tmp:
        measured.to_csv(Path(tmp) / "samples.csv")
        samples = load_samples(Path(tmp) / "samples.csv")
    outcome = calibrate_samples(samples, load_robot(ROBOT), load_setup(SETUP), setup_where=str(SETUP))
    return measured, outcome


def table_tcp(outcome, q_rad: np.ndarray) -> np.ndarray:
    """The calibrated table's TCP (N, 3) [mm, its base frame] at readings ``q_rad`` (N, 6)."""
    x = outcome.calibration.x
    return tcp_position(dh_table(x), q_rad, outcome.model.tcp_in_flange(x))


def tracker_map(world: World, outcome, q_deg: np.ndarray, rng: np.random.Generator):
    """The map of a tracker's rows at readings ``q_deg`` (N, 6), in the table's frame registered
    onto the truth there; None where it stays off."""
    q = np.radians(q_deg)
    p_table = table_tcp(outcome, q)
    rot, t = rigid_fit(p_table, world.true_tcp_mm(q_deg))
    measured = (world.true_tcp_mm(q_deg) + rng.normal(0, TRACKER_MM, p_table.shape) - t) @ rot
    x = outcome.calibration.x
    return fit_map(q, measured - p_table, dh_table(x), outcome.model.tcp_in_flange(x))


def ideal(world: World, measured, program: np.ndarray, rng: np.random.Generator) -> dict:
    """``at_program``'s errors of the true table (``world.true``) and its map from a tracker's rows
    at the measured poses: the unmodelled error alone, as a perfect calibration leaves it."""
    q = np.radians(measured.q_true_deg)
    seen = world.true_tcp_mm(measured.q_true_deg) - world.true.tcp(measured.q_true_deg)
    found = fit_map(q, seen + rng.normal(0, TRACKER_MM, seen.shape), world.true.dh, world.true.tool)
    error = world.true_tcp_mm(program) - world.true.tcp(program)
    out = {"table": error, "map": error, "variance": None, "found": found}
    if found is not None:
        mean, out["variance"] = found.predict(np.radians(program))
        out["map"] = error - mean
    return out


def drawstring_map(outcome):
    """The map of the calibration's own rows as ``station calibrate`` fits it
    (``calib.absorbed_angles.fit_model_map``); None where it stays off."""
    return fit_model_map(outcome.model, outcome.calibration.x, outcome.calibration.identified)


def at_program(world: World, outcome, found, rows_deg: np.ndarray, program: np.ndarray) -> dict:
    """Errors [mm] (P, 3) of the table alone and with the map ``found`` at the program's poses
    (each prediction's frame registered onto the truth at the measured poses ``rows_deg``: the map
    moves the table, frame and all, where it undoes what the table absorbed), and the map's
    variance (P,) [mm^2] there."""
    out = {"table": registered_error(world, outcome, None, rows_deg, program), "variance": None}
    out["map"] = out["table"]
    if found is not None:
        out["map"] = registered_error(world, outcome, found, rows_deg, program)
        out["variance"] = found.predict(np.radians(program))[1]
    return out


def registered_error(world: World, outcome, found, rows_deg: np.ndarray, program: np.ndarray) -> np.ndarray:
    """The truth minus the table's (plus the map ``found``'s) TCP (P, 3) [mm] at the program's
    poses, the prediction's frame registered onto the truth at the measured poses ``rows_deg``."""

    def predicted(q_deg):
        q = np.radians(q_deg)
        return table_tcp(outcome, q) + (0.0 if found is None else found.predict(q)[0])

    rot, t = rigid_fit(predicted(rows_deg), world.true_tcp_mm(rows_deg))
    return world.true_tcp_mm(program) - (predicted(program) @ rot.T + t)


def rms(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(error**2, axis=1))))


def one_cell(seed: int, unmodelled: Unmodelled | None, plan, program, kinds) -> dict:
    """A cell's figures per kind of map rows, its robot carrying ``unmodelled`` (None: nothing)."""
    world = World.create(seed)
    if unmodelled is not None:
        world = dataclasses.replace(world, unmodelled=unmodelled)
    measured, outcome = session(world, plan, seed)
    near = covered(np.radians(measured.q_deg), np.radians(program))
    out = {"seed": seed, "near_poses": int(near.sum())}
    for kind in kinds:
        t0 = time.perf_counter()
        rng = np.random.default_rng([seed, 11])
        if kind == "ideal":
            e = ideal(world, measured, program[near], rng)
            found = e["found"]
        else:
            found = (
                tracker_map(world, outcome, measured.q_deg, rng)
                if kind == "tracker"
                else drawstring_map(outcome)
            )
            e = at_program(world, outcome, found, measured.q_true_deg, program[near])
        inside = None
        if found is not None:
            inside = float(np.mean(np.sum(e["map"] ** 2, axis=1) <= CHI2_3_95 * e["variance"]))
        out[kind] = {
            "on": found is not None,
            "table_rmse_mm": rms(e["table"]),
            "map_rmse_mm": rms(e["map"]),
            "inside_95": inside,
            "fit_s": time.perf_counter() - t0,
            "errors": {k: e[k].tolist() for k in ("table", "map")},
            "variance": None if e["variance"] is None else e["variance"].tolist(),
        }
    return out


def summary(cells: list[dict], null: list[dict], kinds, noise_mm: float) -> dict:
    """The done-when figures pooled over the seeds."""
    out = {}
    for kind in kinds:
        on = [c[kind] for c in cells if c[kind]["on"]]
        table = np.vstack([np.array(c[kind]["errors"]["table"]) for c in cells])
        mapped = np.vstack([np.array(c[kind]["errors"]["map"]) for c in cells])
        inside = [
            np.sum(np.array(c["errors"]["map"]) ** 2, axis=1) <= CHI2_3_95 * np.array(c["variance"])
            for c in on
        ]
        out[kind] = {
            "cells": len(cells),
            "map_on": len(on),
            "program_poses": int(len(table)),
            "table_rmse_mm": rms(table),
            "map_rmse_mm": rms(mapped),
            "worst_cell_map_rmse_mm": max(c[kind]["map_rmse_mm"] for c in cells),
            "limit_mm": 2 * noise_mm,
            "inside_95": float(np.mean(np.concatenate(inside))) if inside else None,
            "null_cells": len(null),
            "null_map_off": sum(not c[kind]["on"] for c in null),
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seeds", type=int, default=20, help="cells with and cells without the error (default 20)"
    )
    ap.add_argument("--near-poses", type=int, default=60, help="contacts --near adds (default 60)")
    ap.add_argument("--error", choices=tuple(ERRORS), default="ur10-like", help="the cells' unmodelled error")
    ap.add_argument("--rows", choices=("drawstring", "tracker", "ideal", "all"), default="all")
    ap.add_argument("--json", type=Path, help="write every cell's figures here")
    args = ap.parse_args(argv)
    kinds = ("drawstring", "tracker", "ideal") if args.rows == "all" else (args.rows,)
    t0 = time.perf_counter()
    program = program_deg()
    plan = near_plan(program, args.near_poses)
    print(f"plan: {len(plan)} poses ({args.near_poses} near the program's {len(program)}), "
          f"{time.perf_counter() - t0:.1f} s", flush=True)  # fmt: skip
    cells, null = [], []
    for seed in range(args.seeds):
        for unmodelled, into in ((ERRORS[args.error], cells), (None, null)):
            into.append(one_cell(seed, unmodelled, plan, program, kinds))
            c = into[-1]
            figures = "; ".join(
                f"{k}: map {'on' if c[k]['on'] else 'off'}, table {c[k]['table_rmse_mm']:.4f} -> "
                f"{c[k]['map_rmse_mm']:.4f} mm, inside 95 % {c[k]['inside_95']}"
                for k in kinds
            )
            print(
                f"seed {seed} {args.error if unmodelled else 'none':9s} ({c['near_poses']} near): {figures}",
                flush=True,
            )
    figures = summary(cells, null, kinds, World.create(0).noise.length_mm)
    print(json.dumps(figures, indent=2))
    print(f"{time.perf_counter() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps({"summary": figures, "cells": cells, "null": null}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
