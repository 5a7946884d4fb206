"""Files for a simulated calibration: the setup a person would measure, samples and a hold-out set,
written in the contract's formats so they run through ``station`` like a real station's."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomli_w

import configs
from sim_fixtures.world import SampleSet, World


@dataclass(frozen=True)
class Scenario:
    """Paths of a written scenario and the world and sample sets behind them."""

    world: World
    robot: Path
    setup: Path
    samples: Path
    holdout: Path
    train: SampleSet
    test: SampleSet


def setup_dict(world: World, rng: np.random.Generator) -> dict:
    """The setup TOML content: rough anchor/offset, instrument noise, each line's dial axis."""
    rough = world.rough_setup(rng)
    return {
        "drawstring": {
            "anchor_mm": [round(float(v), 1) for v in rough["anchor_mm"]],
            "length_offset_mm": round(float(rough["length_offset_mm"]), 1),
            "sigma_mm": world.noise.length_mm,
        },
        "dial": {"sigma_mm": world.noise.dial_mm},
        "lines": [{"id": ln.id, "dial_axis": [float(v) for v in ln.dial_axis]} for ln in world.lines],
    }


def write_scenario(
    folder: Path,
    *,
    seed: int = 0,
    n_lines: int = 3,
    n_per_line: int = 70,
    n_holdout_per_line: int = 20,
    outlier_fraction: float = 0.0,
) -> Scenario:
    """Create a world from ``seed`` and write robot.toml, setup.toml, samples.csv, holdout.csv."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    world = World.create(seed, n_lines=n_lines)
    rng = np.random.default_rng(seed + 1000)
    train = world.sample_set(n_per_line, rng, outlier_fraction)
    test = world.sample_set(n_holdout_per_line, rng)
    paths = {name: folder / name for name in ("robot.toml", "setup.toml", "samples.csv", "holdout.csv")}
    paths["robot.toml"].write_text(configs.path("robots/hsr_jr680.toml").read_text())
    paths["setup.toml"].write_text(tomli_w.dumps(setup_dict(world, rng)))
    train.to_csv(paths["samples.csv"])
    test.to_csv(paths["holdout.csv"])
    return Scenario(world, *paths.values(), train, test)
