"""The accuracy matrix: simulated cells times the setups the contract lets a user write, each
calibrated by ``station calibrate``'s service and judged against the simulated truth.

    python benchmarks/accuracy_matrix.py [--seeds 3] [--write-baseline]

Cells (:data:`CELLS`): the paper's HSR-JR680 (``World.create``), a UR10 and an ABB IRB 2600 in
Craig's modified D-H (``configs/setups/irb2600.toml``), each with machining errors drawn from the
simulator's tolerances. Setups (:data:`VARIANTS`): the dial's axis stated, the dial gating captures
without an axis (the paper's use: the operator brings the dial to about zero, readings within
+-0.01 mm, lines free or given with their geometry), no dial at all, on 1, 2 or 3 gauge lines,
with 3 % gross drawstring readings, and a laser tracker's positions. Per cell, setup and seed: the
true workspace error (1000 random poses in the joint limits, after a rigid fit, as ``station demo``
prints it) and whether it lies inside the report's 95 % bound.

The guard tier (``tests/guard/test_accuracy_matrix.py``) runs the default seeds and compares with
``benchmarks/accuracy_baseline.json``: a cell worse beyond its seeds' spread (:func:`regressions`)
fails it. ``--write-baseline`` rewrites that file; commit it only with a message that says why.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import configs
from calib.kinematics import dh_table, tcp_position
from calib.metrics import aligned_errors
from calib.position import rotation_from_vector
from sim_fixtures.world import DEFAULT_LINES, GaugeLine, Noise, Placement, World
from station.commands.sim import nominal_robot, placement
from station.formats.samples import Samples
from station.formats.tables import SetupFile, load_robot, load_setup
from station.jobs.calibration import calibrate_samples

BASELINE = Path(__file__).with_name("accuracy_baseline.json")
SEEDS = 3
"""Seeds per cell and setup in the guard tier."""
WORKSPACE_POSES = 1000
READINGS = 5
"""Drawstring and dial readings averaged per capture, as ``station sample`` takes them."""
PAPER_PLACEMENT_MM = 0.01
"""How far off the edge the operator leaves the tool when bringing the dial to about zero."""
SAMPLES_PER_LINE = {1: 120, 2: 60, 3: 45}
TRACKER_POSES = 120
SPREAD_FLOOR = 0.02
"""A cell's allowed worsening is at least this share of its baseline mean (last digits of a BLAS)."""


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


UR10_LINES = (
    GaugeLine(0, np.array([700.0, 0.0, 100.0]), _unit([0, 1, 0]), 400.0, _unit([0, 0, 1]), _unit([0, 0, -1])),
    GaugeLine(
        1, np.array([500.0, 500.0, 300.0]), _unit([1, 0, 0]), 300.0, _unit([0, 0, 1]), _unit([0, 0, -1])
    ),
    GaugeLine(
        2,
        np.array([750.0, -350.0, 450.0]),
        _unit([-0.2, 0, 1]),
        300.0,
        _unit([-1, 0, -0.2]),
        _unit([1, 0, 0.2]),
    ),
)
"""A UR10 cell's gauge lines: two edges met from above, one met from the side (the dial reads
positive against the approach)."""


@dataclass(frozen=True)
class Cell:
    """A simulated cell: its robot file and the placement the truth is drawn around."""

    name: str
    robot_file: str
    placement: Placement

    def world(self, seed: int, n_lines: int, noise: Noise) -> World:
        nominal = nominal_robot(self.robot)
        cell = dataclasses.replace(self.placement, lines=self.placement.lines[:n_lines])
        return World.around(nominal, cell, seed, noise)

    @property
    def robot(self):
        return load_robot(configs.path(self.robot_file))


def _irb2600_placement() -> Placement:
    path = configs.path("setups/irb2600.toml")
    return placement(load_setup(path), str(path))


CELLS = {
    "jr680": Cell(
        "jr680",
        "robots/hsr_jr680.toml",
        Placement(np.array([-800.0, 600.0, -600.0]), 200.0, DEFAULT_LINES, 0.0),
    ),
    "ur10": Cell(
        "ur10", "robots/ur10.toml", Placement(np.array([600.0, -600.0, -400.0]), 200.0, UR10_LINES, 0.5)
    ),
    "irb2600 (mdh)": Cell("irb2600 (mdh)", "robots/abb_irb2600.toml", _irb2600_placement()),
}


@dataclass(frozen=True)
class Variant:
    """A setup a user may write: how the dial is used (``axis`` stated, ``gated`` without an axis,
    ``none``), on how many lines, whether the setup gives the lines' geometry, gross readings; or a
    tracker's positions (``dial`` None)."""

    dial: str | None
    n_lines: int = 3
    lines_given: bool = True
    gross: float = 0.0


VARIANTS = {
    "axis, 3 lines": Variant("axis", 3),
    "axis, 2 lines": Variant("axis", 2),
    "axis, 1 line": Variant("axis", 1),
    "gated, 3 lines free": Variant("gated", 3, lines_given=False),
    "gated, 3 lines given": Variant("gated", 3),
    "gated, 2 lines free": Variant("gated", 2, lines_given=False),
    "gated, 1 line free": Variant("gated", 1, lines_given=False),
    "gated, 1 line, 3 % gross": Variant("gated", 1, lines_given=False, gross=0.03),
    "axis, 3 lines, 3 % gross": Variant("axis", 3, gross=0.03),
    "no dial, 3 lines": Variant("none", 3, lines_given=False),
    "no dial, 1 line": Variant("none", 1, lines_given=False),
    "tracker": Variant(None),
}


def setup_file(world: World, variant: Variant, rng: np.random.Generator) -> SetupFile:
    """The setup a person writes for ``world``: rough anchor and offset, the instruments' noise and,
    as ``variant`` says, each line's dial axis and geometry."""
    rough = world.rough_setup(rng)
    content: dict = {
        "drawstring": {
            "anchor_mm": [round(float(v), 1) for v in rough["anchor_mm"]],
            "length_offset_mm": round(float(rough["length_offset_mm"]), 1),
            "sigma_mm": world.noise.length_mm,
        },
    }
    if variant.dial != "none":
        content["dial"] = {"sigma_mm": world.noise.dial_mm}
    lines = []
    for ln in world.lines if variant.lines_given else ():
        entry = {
            "id": ln.id,
            "point_mm": [float(v) for v in ln.centre],
            "direction": [float(v) for v in ln.direction],
            "length_mm": ln.length_mm,
            "approach": [float(v) for v in ln.approach],
        }
        if variant.dial == "axis":
            entry["dial_axis"] = [float(v) for v in ln.dial_axis]
        lines.append(entry)
    content["lines"] = lines
    return SetupFile.model_validate(content)


def session(cell: Cell, variant: Variant, seed: int):
    """The samples, setup (None for a tracker) and world of one simulated session."""
    paper = variant.dial == "gated"
    noise = Noise(placement_mm=PAPER_PLACEMENT_MM) if paper else Noise()
    world = cell.world(seed, variant.n_lines, noise)
    rng = np.random.default_rng([seed, 1000])
    if variant.dial is None:
        return tracker_samples(world, rng), None, world
    s = world.sample_set(SAMPLES_PER_LINE[variant.n_lines], rng, variant.gross, READINGS)
    dial = np.full(len(s.line), np.nan) if variant.dial == "none" else s.dial_mm
    samples = Samples(f"{cell.name} seed {seed}", "drawstring", s.q_deg, s.length_mm, dial, s.line)
    return samples, setup_file(world, variant, rng), world


def tracker_samples(world: World, rng: np.random.Generator) -> Samples:
    """A laser tracker's positions (0.02 mm per axis) of the true TCP at random poses, in the
    tracker's own frame."""
    q = world.random_configurations(TRACKER_POSES, rng)
    p = world.true_tcp_mm(q) @ rotation_from_vector(np.array([0.1, -0.2, 2.5])).T + [2500.0, -1000.0, 200.0]
    p += rng.normal(0, 0.02, p.shape)
    n = len(q)
    return Samples("tracker", "position", q, p, np.full(n, np.nan), np.full(n, -1))


def true_rmse(world: World, x: np.ndarray, tool: np.ndarray) -> float:
    """The table's true workspace error [mm] with the TCP at ``tool`` (flange frame): random poses,
    rigid fit (``station demo``'s)."""
    q = world.random_configurations(WORKSPACE_POSES, np.random.default_rng(7))
    p = tcp_position(dh_table(x), np.radians(q), tool)
    return float(np.sqrt(np.mean(aligned_errors(p, world.true_tcp_mm(q)) ** 2)))


def run_one(cell_name: str, variant_name: str, seed: int) -> dict:
    """One session calibrated: ``true_mm``, the report's ``bound95_mm`` and ``refused``."""
    cell, variant = CELLS[cell_name], VARIANTS[variant_name]
    samples, setup, world = session(cell, variant, seed)
    outcome = calibrate_samples(samples, cell.robot, setup)
    report, x = outcome.report, outcome.calibration.x
    return {
        "true_mm": true_rmse(world, x, outcome.model.tcp_in_flange(x)),
        "bound95_mm": report.workspace.predicted_rmse_95_mm,
        "refused": bool(report.fit_check and report.fit_check.refusal),
    }


def run(seeds: int, cells=None, variants=None, progress=None) -> dict:
    """The matrix: ``{cell: {variant: [run_one per seed]}}``."""
    out: dict = {}
    for cell_name in cells or CELLS:
        for variant_name in variants or VARIANTS:
            runs = [run_one(cell_name, variant_name, seed) for seed in range(seeds)]
            out.setdefault(cell_name, {})[variant_name] = runs
            if progress:
                progress(cell_name, variant_name, runs)
    return out


def summary(runs: list[dict]) -> dict:
    """Mean true error [mm], its seeds' standard error, and how many lie inside their 95 % bound."""
    true = np.array([r["true_mm"] for r in runs])
    inside = sum(r["true_mm"] <= r["bound95_mm"] for r in runs)
    spread = float(np.std(true, ddof=1) / np.sqrt(true.size)) if true.size > 1 else 0.0
    return {"mean_true_mm": float(true.mean()), "spread_mm": spread, "inside": int(inside), "n": len(runs)}


def regressions(now: dict, baseline: dict) -> list[str]:
    """Each cell and setup worse than the baseline: a mean true error above the baseline's by more
    than the baseline seeds' standard error (at least ``SPREAD_FLOOR`` of it), or fewer seeds inside
    their 95 % bound; a cell or setup the baseline has and ``now`` lacks."""
    found = []
    for cell, variants in baseline.items():
        for variant, base_runs in variants.items():
            runs = now.get(cell, {}).get(variant)
            if runs is None:
                found.append(f"{cell} / {variant}: not run")
                continue
            was, got = summary(base_runs), summary(runs)
            slack = max(was["spread_mm"], SPREAD_FLOOR * was["mean_true_mm"])
            if got["mean_true_mm"] > was["mean_true_mm"] + slack:
                found.append(
                    f"{cell} / {variant}: true workspace error {got['mean_true_mm']:.3f} mm, baseline "
                    f"{was['mean_true_mm']:.3f} +- {slack:.3f} mm"
                )
            if got["inside"] < was["inside"]:
                found.append(
                    f"{cell} / {variant}: {got['inside']} of {got['n']} inside the 95 % bound, "
                    f"baseline {was['inside']} of {was['n']}"
                )
    return found


def table(results: dict) -> str:
    """The matrix as a Markdown table: mean true error (inside the 95 % bound / seeds) per cell."""
    cells = list(results)
    variants = list(next(iter(results.values())))
    rows = ["| setup | " + " | ".join(cells) + " |", "|---|" + "---|" * len(cells)]
    for v in variants:
        parts = []
        for c in cells:
            s = summary(results[c][v])
            parts.append(f"{s['mean_true_mm']:.3f} mm ({s['inside']}/{s['n']})")
        rows.append(f"| {v} | " + " | ".join(parts) + " |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=SEEDS)
    parser.add_argument("--write-baseline", action="store_true", help=f"rewrite {BASELINE.name}")
    parser.add_argument("--json", type=Path, help="also write the per-seed figures here")
    parser.add_argument("--cells", nargs="+", choices=list(CELLS), help="only these cells")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), help="only these setups")
    args = parser.parse_args()
    t0 = time.perf_counter()

    def progress(cell, variant, runs):
        s = summary(runs)
        print(f"{cell:>14} | {variant:<26} | {s['mean_true_mm']:.3f} mm, {s['inside']}/{s['n']} inside "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip

    results = run(args.seeds, args.cells, args.variants, progress)
    print(table(results))
    if BASELINE.exists() and not args.write_baseline and args.seeds == SEEDS:
        base = json.loads(BASELINE.read_text())
        base = {c: {v: r for v, r in vs.items() if v in results.get(c, {})} for c, vs in base.items()}
        found = regressions(results, base)
        print("against the baseline: " + ("; ".join(found) if found else "no cell worse"))
    if args.write_baseline:
        if args.cells or args.variants or args.seeds != SEEDS:
            parser.error(f"--write-baseline takes the whole matrix at {SEEDS} seeds")
        BASELINE.write_text(json.dumps(results, indent=1) + "\n")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
