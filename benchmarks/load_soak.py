"""``station demo`` (the simulated cell, x40) while busy loops load the machine, then an audit of what
was stored.

    python benchmarks/load_soak.py [--busy 3] [--plan-size 45] [--seed 0] [--json]

``--busy`` processes spin on the CPU for at most ``--busy-s`` seconds (ended with the demo, and by
their own deadline if this script dies). The demo is the real command in a child process
(``python -m station.cli demo --no-viewer``); its log is read from its stdout. The audit of
``session/samples.csv`` and ``session/raw.csv`` against ``plan.csv``:

- ``away``: samples whose joints lie more than ``match_deg`` (max |dq|) from the planned joints of
  the target they are stored under (the worst distance is ``worst_away_deg``);
- ``torn``: a row of the wrong width, a value that is not a finite number, or a sample without
  its K raw readings;
- ``duplicated``: targets or sample ids stored twice;
- ``lost``: sample ids below the highest stored (in samples.csv or raw.csv) without their row in
  samples.csv; ``unmeasured``:
  plan targets without a sample (the session may end early on its accuracy goal);
- ``rejected``: captures the session rejected and took again (their reasons counted by kind);
- ``true_workspace_mm``: the demo's own check, the corrected table against the simulated truth on
  1000 random poses (lmlc), and ``exit``, ``wall_s``.
"""

from __future__ import annotations

import argparse
import collections
import csv
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomllib

ROOT = Path(__file__).resolve().parents[1]
BUSY = "import time\nend = time.monotonic() + {s}\nwhile time.monotonic() < end:\n    pass\n"
TRUTH = re.compile(r"calibrate: lmlc .*true workspace error \(simulation.*?\) ([\d.]+) -> ([\d.]+) mm RMS")
REJECTED = re.compile(r"capture at target \d+ rejected: (.*?)(?: \(|;|$)")


def busy_loops(n: int, seconds: float) -> list[subprocess.Popen]:
    """``n`` processes spinning for ``seconds`` at most."""
    return [subprocess.Popen([sys.executable, "-c", BUSY.format(s=seconds)]) for _ in range(n)]


def run_demo(out: Path, plan_size: int | None, seed: int, timeout_s: float) -> tuple[int, str, float]:
    cmd = [sys.executable, "-m", "station.cli", "demo", "--no-viewer", "--out", str(out), "--seed", str(seed)]
    if plan_size:
        cmd += ["--plan-size", str(plan_size)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.monotonic()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env, cwd=ROOT)
        code, log = proc.returncode, proc.stdout + proc.stderr
    except subprocess.TimeoutExpired as exc:
        code, log = (
            "timeout",
            (exc.stdout or b"").decode() if isinstance(exc.stdout, bytes) else (exc.stdout or ""),
        )
    return code, log, time.monotonic() - t0


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    if not path.is_file():
        return [], []
    with path.open(newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def audit(out: Path, log: str) -> dict:
    """The stored session against its plan (see the module notes)."""
    config = tomllib.loads((out / "station.toml").read_text()) if (out / "station.toml").is_file() else {}
    session = config.get("session", {})
    match_deg, readings = float(session.get("match_deg", 2.0)), int(session.get("readings", 5))
    _, plan_rows = read_csv(out / "plan.csv")
    planned = {int(r["target"]): np.array([float(r[f"q{i}_deg"]) for i in range(1, 7)]) for r in plan_rows}
    header, rows = read_csv(out / "session" / "samples.csv")
    _, raw = read_csv(out / "session" / "raw.csv")
    raw_count = collections.Counter(r["sample"] for r in raw)
    torn, away, worst = 0, 0, 0.0
    for row in rows:
        values = [row.get(k) for k in header if k not in ("dial_mm", "dial_spread_mm")]
        try:
            numbers = [float(v) for v in values]
        except (TypeError, ValueError):
            torn += 1
            continue
        if (
            len(row) != len(header)
            or not all(map(math.isfinite, numbers))
            or raw_count[row["sample"]] != readings
        ):
            torn += 1
            continue
        q = np.array([float(row[f"q{i}_deg"]) for i in range(1, 7)])
        distance = float(np.max(np.abs(q - planned[int(row["target"])])))
        worst = max(worst, distance)
        away += distance > match_deg
    stored_ids = {r["sample"] for r in rows}
    ids = sorted(int(i) for i in stored_ids | set(raw_count))
    expected = {str(i) for i in range(ids[-1] + 1)} if ids else set()
    targets = [r["target"] for r in rows]
    truth = TRUTH.search(log)
    return {
        "plan_targets": len(planned),
        "stored": len(rows),
        "away": away,
        "worst_away_deg": round(worst, 4),
        "match_deg": match_deg,
        "torn": torn,
        "duplicated": (len(targets) - len(set(targets))) + (len(rows) - len(stored_ids)),
        "lost": len(expected - stored_ids),
        "unmeasured": len(set(map(str, planned)) - set(targets)),
        "rejected": dict(collections.Counter(REJECTED.findall(log))),
        "true_workspace_mm": float(truth.group(2)) if truth else None,
        "true_workspace_nominal_mm": float(truth.group(1)) if truth else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy", type=int, default=3, help="busy-loop processes (default 3)")
    ap.add_argument("--busy-s", type=float, default=600.0, help="each busy loop ends after this (s)")
    ap.add_argument("--plan-size", type=int, default=None, help="poses in the demo's plan (default: its own)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout-s", type=float, default=900.0, help="the demo is killed after this (s)")
    ap.add_argument("--keep", type=Path, help="keep the demo's folder here (default: a temporary one)")
    ap.add_argument("--json", action="store_true", help="end with one JSON line")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="load-soak-") as tmp:
        out = args.keep or Path(tmp) / "demo"
        loops = busy_loops(args.busy, args.busy_s)
        try:
            code, log, wall_s = run_demo(out, args.plan_size, args.seed, args.timeout_s)
        finally:
            for p in loops:
                p.kill()
                p.wait()
        result = {"busy": args.busy, "plan_size": args.plan_size, "exit": code, "wall_s": round(wall_s, 1)}
        result.update(audit(out, log))
    if code != 0:
        print(log[-3000:])
    for line in log.splitlines():
        if line.startswith(("plan:", "session:", "calibrate: lmlc")) or "rejected" in line:
            print(line)
    r = result
    print(
        f"load soak ({args.busy} busy loops): exit {code}, {r['stored']}/{r['plan_targets']} stored, "
        f"away {r['away']} (worst {r['worst_away_deg']} deg, match {r['match_deg']:g}), torn {r['torn']}, "
        f"duplicated {r['duplicated']}, lost {r['lost']}, rejected {sum(r['rejected'].values())}, "
        f"true workspace error {r['true_workspace_mm']} mm, {wall_s:.0f} s"
    )
    if args.json:
        print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
