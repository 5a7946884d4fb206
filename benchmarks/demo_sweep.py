"""The demo's cell measured statically and by sweeps (issue 37): robot time and true workspace error.

    python benchmarks/demo_sweep.py [--seeds 0 1 2 3] [--only static|sweep] [--runs 1]

Per seed, ``station demo --seed S`` and ``station demo --sweep --seed S`` in subprocesses (each
its own simulated devices, one after the other), and from their output the robot time (the
simulated seconds the program takes to walk the plan once) and the true workspace error after
LMLC (1,000 random poses, rigid base re-fit). The target: each sweep demo within 120 s of robot
time, its error no worse than the static demo's on the same seed; and the predicted workspace
error with its 95 % bound beside the true one (the bound must hold on every seed). Takes about 10
minutes a seed (a sweep alone about 2). ``--runs N``: each demo N times (a sweep's rows fall on
other readings of the stream each run, so its figure moves; the static demo's barely does), a row
per run, then per seed each kind's median and range of the true error and, with both kinds, how
many sweep runs came out no worse than the static demo's median.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROBOT = re.compile(r"^robot: +([\d.]+) s of robot time", re.M)
PREDICTED = re.compile(r"^calibrate: lmlc .*predicted workspace ([\d.]+) mm \(95 %: ([\d.]+)\)", re.M)
TRUE = re.compile(
    r"calibrate: lmlc .*true workspace error \(simulation, 1000 random poses\) [\d.]+ -> ([\d.]+) mm"
)


def demo(seed: int, sweep: bool, folder: Path) -> tuple[float, float, float, float, int]:
    """Robot time [s], true workspace error after LMLC [mm], its predicted error and 95 % bound [mm]
    and the exit code of one demo run."""
    out = folder / f"{'sweep' if sweep else 'static'}-{seed}"
    argv = [
        sys.executable,
        "-m",
        "station.cli",
        "demo",
        "--no-viewer",
        "--seed",
        str(seed),
        "--out",
        str(out),
    ]
    done = subprocess.run(argv + (["--sweep"] if sweep else []), capture_output=True, text=True)
    found = [r.search(done.stdout) for r in (ROBOT, TRUE, PREDICTED)]
    if done.returncode != 0 or not all(found):
        print(done.stdout[-3000:], done.stderr[-3000:], file=sys.stderr)
    robot, true, predicted = (float(m[1]) if m else float("nan") for m in found)
    bound = float(found[2][2]) if found[2] else float("nan")
    return robot, true, predicted, bound, done.returncode


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    parser.add_argument("--only", choices=("static", "sweep"))
    parser.add_argument("--runs", type=int, default=1)
    args = parser.parse_args()
    kinds = [k for k in ("static", "sweep") if args.only in (None, k)]
    folder = Path(tempfile.mkdtemp(prefix="demo-sweep-"))
    columns = "robot time [s] | true error [mm] | predicted [mm] | 95 % bound [mm] | bound / true | exit"
    print("seed | run | " + " | ".join(" | ".join(f"{k} {c}" for c in columns.split(" | ")) for k in kinds))
    summary = []
    for seed in args.seeds:
        trues = {kind: [] for kind in kinds}
        for run in range(args.runs):
            cells = []
            for kind in kinds:
                robot, true, predicted, bound, code = demo(seed, kind == "sweep", folder / f"run-{run}")
                trues[kind].append(true)
                cells += [f"{robot:.1f}", *(f"{v:.3f}" for v in (true, predicted, bound))]
                cells += [f"{bound / true:.2f}", str(code)]
            print(f"{seed} | {run} | " + " | ".join(cells), flush=True)
        summary.append(spread(seed, trues))
    if args.runs > 1:
        print("\n".join(summary))


def spread(seed: int, trues: dict[str, list[float]]) -> str:
    """One seed's runs: each kind's median and range of the true error [mm], and with both kinds
    the sweep runs no worse than the static demo's median."""
    said = [
        f"{kind} median {np.median(v):.3f} ({min(v):.3f}-{max(v):.3f}) over {len(v)} runs"
        for kind, v in trues.items()
    ]
    if len(trues) == 2:
        static = float(np.median(trues["static"]))
        said.append(f"{sum(t <= static for t in trues['sweep'])} sweep runs no worse than {static:.3f}")
    return f"seed {seed}: " + "; ".join(said)


if __name__ == "__main__":
    main()
