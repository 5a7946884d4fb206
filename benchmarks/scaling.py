"""Speed of each calibrator and how it grows with the number of samples and of gauge-block lines.

Samples on simulated JR680 cells (``World.create(seed, n_lines)``), the common start of
``station.jobs.comparison`` (setup fit + identification), then each method timed alone:

- LMLC and Gauss-Newton at 200, 2,000 and 20,000 samples on one line (median of 3 runs below 20,000);
- the filters (EKF, UKF, PF) at 200 and 2,000 (default budgets);
- the global searches (PSO, DE, SA) at 200 and 2,000 with a reduced budget (``max_iter=30``):
  their cost is their evaluation count times the time of one evaluation, shown per evaluation;
- LMLC on 600 samples over 1 and over 3 lines.

    python benchmarks/scaling.py [--out benchmarks/RESULTS-compare.md]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.baselines import BaselineOptions, run_method  # noqa: E402
from calib.calibrate import calibrate  # noqa: E402
from calib.drawstring import DrawstringFrame, DrawstringLineModel, DrawstringSamples, DrawstringSetup  # noqa: E402
from sim_fixtures.world import World  # noqa: E402
from station.jobs.comparison import LABELS  # noqa: E402

GLOBAL_BUDGET = BaselineOptions(max_iter=30)
PLAN = {
    "lmlc": (200, 2000, 20000),
    "gn": (200, 2000, 20000),
    "ekf": (200, 2000),
    "ukf": (200, 2000),
    "pf": (200, 2000),
    "pso": (200, 2000),
    "de": (200, 2000),
    "sa": (200, 2000),
}


def cell(n_lines: int, n_per_line: int, seed: int = 0):
    """Model and common start (x0, free) for ``n_per_line`` samples on each of ``n_lines`` lines."""
    world = World.create(seed, n_lines=n_lines)
    rng = np.random.default_rng(seed + 1000)
    s = world.sample_set(n_per_line, rng)
    rough = world.rough_setup(rng)
    setup = DrawstringSetup(
        rough["anchor_mm"], rough["length_offset_mm"], rough["sigma_mm"], dial_axis=rough["dial_axes"]
    )
    data = DrawstringSamples(np.radians(s.q_deg), s.length_mm, s.dial_mm, s.line)
    dh0 = world.nominal.dh
    frame = DrawstringFrame.from_nominal(data, setup, dh0, np.zeros(3))
    model = DrawstringLineModel(data, setup, frame, dh0, np.zeros(3))
    start = calibrate(model)
    return model, start.before.x, start.identified


def timed(method, model, x0, free, repeats):
    options = GLOBAL_BUDGET if method in ("pso", "de", "sa") else BaselineOptions()
    runs = [run_method(method, model, x0, free, options) for _ in range(repeats)]
    return float(np.median([r.time_s for r in runs])), runs[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="append the markdown here")
    args = ap.parse_args()
    sizes = sorted({n for ns in PLAN.values() for n in ns})
    cells = {}
    for n in sizes:
        t = time.perf_counter()
        cells[n] = cell(1, n)
        print(f"{n} samples generated in {time.perf_counter() - t:.0f} s", flush=True)
    lines = [
        "## Speed and scaling (one line; time of the method alone, after the common start)",
        "",
        "| method | samples | time s | iterations | evaluations | ms / evaluation |",
        "|---|---|---|---|---|---|",
    ]
    for method, ns in PLAN.items():
        for n in ns:
            t, r = timed(method, *cells[n], repeats=3 if method in ("lmlc", "gn", "ekf") and n < 20000 else 1)
            lines.append(
                f"| {LABELS[method]} | {n} | {t:.3f} | {r.iterations} | {r.nfev} | {1000 * t / r.nfev:.3f} |"
            )
            print(lines[-1], flush=True)
    lines += ["", "| LMLC, 600 samples | time s | iterations |", "|---|---|---|"]
    for n_lines in (1, 3):
        t, r = timed("lmlc", *cell(n_lines, 600 // n_lines), repeats=3)
        lines.append(f"| {n_lines} line(s) | {t:.3f} | {r.iterations} |")
    lines.append("")
    lines.append(f"Global searches (PSO, DE, SA) with max_iter={GLOBAL_BUDGET.max_iter}; defaults elsewhere.")
    text = "\n".join(lines)
    print(text)
    if args.out:
        with args.out.open("a") as fh:
            fh.write(text + "\n\n")


if __name__ == "__main__":
    main()
