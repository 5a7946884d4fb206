"""Time and peak memory of ``station calibrate`` as the rows grow (issue 21 item 6; issue 37's
targets: 100,000 rows <= 10 s, 1,000,000 rows <= 60 s and <= 4 GB).

    python benchmarks/calibrate_scaling.py [--rows 10000 100000 1000000] [--model auto] [--tree DIR]

Each set is a simulated JR680 session (``sim_fixtures.scenario``: 70 configurations on each of 3
gauge lines) measured again and again, each row with fresh instrument noise, up to the row count
(the real case: a long session or repeated captures). The whole command runs in a child process
(interpreter start and CSV loading included); reported: wall seconds, seconds per 1,000 rows, the
child's CPU seconds (user + system: on a shared machine the wall time is the load's as much as the
command's), peak RSS (``os.wait4``), memory per row above the first run's and the load average at
the start. ``--tree`` runs the command of another checkout on the same rows (e.g. a ``git worktree``
of the commit before, for before and after in one run). ``OPENBLAS_NUM_THREADS`` is passed through
as set (on a loaded machine set it to 1: OpenBLAS threads that spin for a core taken by others
slowed a 20,000-row run threefold).

Figures (``OPENBLAS_NUM_THREADS=1``, ``--model auto``; wall s, CPU s, peak MB, load at the start):

- 100,000 rows: 107.2 s, 93.4 CPU s, 1,071 MB before the blocked kinematics and normal equations
  (153cc48, load 1.9); 30.5 s, 30.1 CPU s, 694 MB with them (f4dd7ce, load 2.0).
- 1,000,000 rows: 2,183 s, 8,270 MB (issue 21's run, load 11-12); 340.5 s, 334.4 CPU s, 6,207 MB
  with them (load 2.9): 6.1 KB a row above 100,000 rows.
- Planning back on the row-by-row products, the fits (``station calibrate``'s model, the term
  choice's folds) on ``frame_axes``, one pass over the Jacobian per solver iteration, ``identify``
  on R of its QR: 20,000 rows 5.7 CPU s, 180 MB (19.6 s at load 5.2) against main's 12.8 CPU s,
  311 MB (71.1 s, load 9.6); 100,000 rows 29.9 CPU s, 688 MB (166 s at load 7.2) against main's
  129.7 CPU s, 1,071 MB (593 s, load 7.9); 1,000,000 rows 344.4 CPU s, 6,393 MB (983 s at load
  10, beside the guard tier; not profiled): the (3N, n) Jacobian (about 1.2 GB) and its copies
  (the prior rows appended, the fold subsets) set the memory.
- With the residual map on by default (9fc4305; load 11-16, main's tree in the same session): 20,000
  rows 16.7 CPU s, 1,955 MB on main against 10.0 CPU s, 677 MB after the map's k-d tree neighbours,
  its angle errors' design in blocks, the folds' normal equations in one pass, the prior's rows into
  the model's Jacobian and the dial check's blocked QR; 100,000 rows 68.0 CPU s, 9,548 MB against
  35.7 CPU s, 738 MB (397 s wall at load 13). 1,000,000 rows: stopped at 110 CPU s (load 12-19),
  4,250 MB by then (docs/results/speed.md says what is left).
- The robust fits coarse to fine (``calib.calibrate.COARSE_ROWS``: each round first on 20,000 of
  the rows, then on all from there; main's tree in the same session, load 6-9): 100,000 rows
  30.3 CPU s, 1,350 MB on main against 25.4 CPU s, 1,234 MB (91.3 s wall); 1,000,000 rows
  263.6 CPU s, 5,134 MB on main against 191.2 CPU s, 5,272 MB (542 s wall at load 8.6); 20,000
  rows the same code (13.3 and 11.9 CPU s: the load's spread). Same answers within the solver's
  tolerance (docs/results/speed.md). The targets are not met.
- ``--model auto``'s choice, the carry-over check and the dial check's dial-free steps on the robust
  fits' draw of 20,000 rows above ``COARSE_ROWS``, the TCP derivatives written in place and
  ``tcp_position`` in blocks (``--rows 20000 100000 1000000``, main's tree first in the same session,
  load 4.4-8.2): 20,000 rows 11.7 against 12.0 CPU s (the report identical); 100,000 rows 22.9 CPU s,
  1,315 MB on main against 18.0 CPU s, 1,339 MB; 1,000,000 rows 203.3 CPU s, 5,112 MB (682 s wall)
  against 80.8 CPU s, 4,516 MB (340 s wall; 74 CPU s and 3,687 MB at load about 4, the peak moving
  3.6-4.5 GB from run to run). The same terms, held parameters and corrected table as main at 100,000
  and 1,000,000 rows (the cross-validation table's figures are the draw's). The memory target is met
  on a lightly loaded machine; the time targets are not.
- The drawstring map's refits from per-fold Gram matrices, its rows thinned before their
  observations are taken, a plain CSV read whole by ``numpy.loadtxt`` (``--rows 100000 1000000``,
  ``--tree`` a worktree of 83d8bba first, then this tree, one session, load 1.0): 100,000 rows 21.2
  CPU s, 1,612 MB against 13.5 CPU s, 991 MB; 1,000,000 rows 79.2 CPU s, 3,601 MB against 66.7 CPU s,
  4,515 MB (three runs of the command alone on the same rows: 61.1-62.5 CPU s, 3,709 MB each). Not met.
- The fits' row loops on both cores (``calib/blocks.py``; the tree of 8d119ae first, then this tree,
  one session, quiet, load 1.0-1.5; wall s, CPU s, peak MB): 100,000 rows 13.1-13.3 s, 969-988 MB
  against 9.1-12.7 s (7 runs, median 10.1; 12.7-17.7 CPU s), 805-808 MB; 1,000,000 rows 62.0-64.1
  s, 3,644 MB against 43.6-57.6 s (4 runs, median 47.6; 63.6-84.0 CPU s), 3,712-3,739 MB. The
  million-row targets met on this quiet machine, the 100,000-row one in 3 runs of 7.
- No Jacobian at a run's last step and one setup-only fit for the term choice's models (the tree of
  09061db first, then this tree, one session, quiet, load 0.8-1.4, a faster machine than the line
  above's): 100,000 rows 6.0-6.4 s, 8.4-8.9 CPU s, 846 MB against 5.5-5.6 s, 7.7-7.8 CPU s, 845 MB;
  1,000,000 rows 28.0-29.1 s, 41.7-43.1 CPU s, 3,707 MB against 26.2-26.5 s, 38.2-38.6 CPU s,
  3,589 MB (2 runs each). Every target met on this machine.
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


def measure(rows: int, model: str, tree: Path = ROOT) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        sc = write_rows(Path(tmp), rows)
        cmd = [sys.executable, "-m", "station.cli", "calibrate", str(sc.samples), "--robot", str(sc.robot)]
        cmd += ["--setup", str(sc.setup), "--out", str(Path(tmp) / "out.toml"), "--model", model]
        load = os.getloadavg()[0]
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, cwd=tree, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        stderr = proc.stderr.read()
        proc.stdout.read()
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.monotonic() - t0
    return {
        "rows": rows,
        "s": seconds,
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "load": load,
        "peak_mb": usage.ru_maxrss / 1024,
        "exit": os.waitstatus_to_exitcode(status),
        "progress": [line for line in stderr.splitlines() if line.startswith("calibrate: ")],
        "err": [line for line in stderr.splitlines() if not line.startswith("calibrate: ")],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, nargs="+", default=[10000, 100000, 1000000])
    parser.add_argument("--model", default="auto", help="station calibrate --model (default auto)")
    parser.add_argument("--tree", type=Path, default=ROOT, help="checkout whose station runs (default this)")
    args = parser.parse_args()
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    print(f"OPENBLAS_NUM_THREADS={threads}, --model {args.model}, station of {args.tree}")
    print(
        f"{'rows':>9} {'s':>8} {'s/1k rows':>10} {'CPU s':>7} {'load':>5} {'peak MB':>9} {'KB/row':>7}",
        end="",
    )
    print("  exit  progress lines")
    first = None
    for rows in args.rows:
        r = measure(rows, args.model, args.tree)
        per_row = (
            "" if first is None else f"{(r['peak_mb'] - first['peak_mb']) * 1e3 / (rows - first['rows']):.1f}"
        )
        first = first or r
        print(
            f"{rows:>9} {r['s']:>8.1f} {r['s'] / rows * 1e3:>10.3f} {r['cpu_s']:>7.1f} {r['load']:>5.1f}"
            f" {r['peak_mb']:>9.0f} {per_row:>7}"
            f"  {r['exit']:>4}  {len(r['progress'])}",
            flush=True,
        )
        for line in r["progress"][-2:] + r["err"][-2:]:
            print(f"{'':10}{line}")


if __name__ == "__main__":
    main()
