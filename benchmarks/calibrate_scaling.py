"""Time and peak memory of ``station calibrate`` as the rows grow (issue 21 item 6).

    python benchmarks/calibrate_scaling.py [--rows 10000 100000 1000000] [--model auto]

Each set is a simulated JR680 session (``sim_fixtures.scenario``: 70 configurations on each of 3
gauge lines) measured again and again, each row with fresh instrument noise, up to the row count
(the real case: a long session or repeated captures). The whole command runs in a child process
(interpreter start and CSV loading included); reported: wall seconds, seconds per 1,000 rows, peak
RSS (``os.wait4``) and memory per row above the 10,000-row run's. Linear scaling shows as a constant
time and memory per row. ``OPENBLAS_NUM_THREADS`` is passed through as set (on a loaded machine set
it to 1: OpenBLAS threads that spin for a core taken by others slowed a 20,000-row run threefold).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from sim_fixtures.scenario import write_scenario  # noqa: E402

CONFIGURATIONS_PER_LINE = 70


def write_rows(folder: Path, rows: int, seed: int = 0):
    """A scenario in ``folder`` whose samples.csv holds ``rows`` rows (see the module notes)."""
    sc = write_scenario(folder, seed=seed, n_lines=3, n_per_line=CONFIGURATIONS_PER_LINE)
    q, lines = sc.train.q_true_deg, sc.train.line
    pick = np.arange(rows) % len(q)
    sc.world.measure(q[pick], lines[pick], np.random.default_rng(seed + 7)).to_csv(sc.samples)
    return sc


def measure(rows: int, model: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        sc = write_rows(Path(tmp), rows)
        cmd = [sys.executable, "-m", "station.cli", "calibrate", str(sc.samples), "--robot", str(sc.robot)]
        cmd += ["--setup", str(sc.setup), "--out", str(Path(tmp) / "out.toml"), "--model", model]
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        stderr = proc.stderr.read()
        proc.stdout.read()
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.monotonic() - t0
    return {
        "rows": rows,
        "s": seconds,
        "peak_mb": usage.ru_maxrss / 1024,
        "exit": os.waitstatus_to_exitcode(status),
        "progress": [line for line in stderr.splitlines() if line.startswith("calibrate: ")],
        "err": [line for line in stderr.splitlines() if not line.startswith("calibrate: ")],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[10000, 100000, 1000000])
    parser.add_argument("--model", default="auto", help="station calibrate --model (default auto)")
    args = parser.parse_args()
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, --model {args.model}")
    print(f"{'rows':>9} {'s':>8} {'s/1k rows':>10} {'peak MB':>9} {'KB/row':>7}  exit  progress lines")
    first = None
    for rows in args.rows:
        r = measure(rows, args.model)
        per_row = (
            "" if first is None else f"{(r['peak_mb'] - first['peak_mb']) * 1e3 / (rows - first['rows']):.1f}"
        )
        first = first or r
        print(
            f"{rows:>9} {r['s']:>8.1f} {r['s'] / rows * 1e3:>10.3f} {r['peak_mb']:>9.0f} {per_row:>7}"
            f"  {r['exit']:>4}  {len(r['progress'])}",
            flush=True,
        )
        for line in r["progress"][-2:] + r["err"][-2:]:
            print(f"{'':10}{line}")


if __name__ == "__main__":
    main()
